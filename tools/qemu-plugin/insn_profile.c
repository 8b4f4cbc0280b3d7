/*
 * Guest-instruction profile of a whole QEMU run, by translation block.
 *
 * Every executed block adds its instruction count to its start address's tally. The tallies
 * are written to `out=FILE` as lines "<start address> <instructions in the block> <times
 * executed>" (hexadecimal address, decimal counts), first line "total <instructions>", every
 * second and at exit: the virtual bench kills QEMU (SIGKILL), so the last file written is the
 * run's profile up to the last second. `tools/qemu-plugin/insn_profile.py` adds the tallies up
 * by the firmware's symbols.
 *
 * Why blocks, not instructions: one callback per block costs QEMU a fraction of what one per
 * instruction does, and a block lies within one function (it ends at every branch).
 *
 * Debian ships no qemu-plugin.h, so the few plugin API functions used are declared here
 * (plugin API version 2, accepted by QEMU 8.x..10.x). One vCPU (mps2-an386): the tallies are
 * plain counters, read unlocked by the writer thread (a count a block behind is good enough).
 *
 * Callers: `watch=ADDR` (hexadecimal, up to 64 of them) also counts, for every block starting
 * at ADDR, the block executed just before it — for a function's entry, its call sites (a
 * `memcpy` of many instructions a step is told apart by who calls it). Written as lines "edge
 * <previous block's start> <ADDR> <times>"; `insn_profile.py --watch ELF NAME...` prints the
 * arguments for named functions.
 *
 * Build: gcc -shared -fPIC -O2 -pthread -o libinsn_profile.so insn_profile.c
 * Use:   NANOCAL_QEMU_PLUGIN=/path/libinsn_profile.so,out=/tmp/prof.txt nanocal campaign ...
 *        (or qemu-system-arm ... -plugin /path/libinsn_profile.so,out=/tmp/prof.txt)
 */
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

typedef uint64_t qemu_plugin_id_t;
typedef struct qemu_info_t qemu_info_t;
struct qemu_plugin_tb;
enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS, QEMU_PLUGIN_CB_R_REGS, QEMU_PLUGIN_CB_RW_REGS };
typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
typedef void (*qemu_plugin_vcpu_udata_cb_t)(unsigned int vcpu_index, void *userdata);
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t id, void *userdata);

void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_tb_trans_cb_t cb);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
uint64_t qemu_plugin_tb_vaddr(const struct qemu_plugin_tb *tb);
void qemu_plugin_register_vcpu_tb_exec_cb(struct qemu_plugin_tb *tb, qemu_plugin_vcpu_udata_cb_t cb,
                                          enum qemu_plugin_cb_flags flags, void *userdata);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, qemu_plugin_udata_cb_t cb, void *userdata);

__attribute__((visibility("default"))) int qemu_plugin_version = 2;

/* One tally per (start address, size) seen; a block translated again finds its tally. */
struct tally {
    uint64_t vaddr;
    uint64_t n_insns;
    volatile uint64_t execs;
    /* a block at a `watch=` address: its predecessors are counted */
    int watched;
    struct tally *next;
};

/* (previous block's start, watched block's start) -> times; inserted under `lock` by the one
 * vCPU thread, walked unlocked by it. */
struct edge {
    uint64_t from;
    uint64_t to;
    volatile uint64_t n;
    struct edge *next;
};

#define BUCKETS 65536
static struct tally *table[BUCKETS];
static struct edge *edges[BUCKETS];
#define MAX_WATCH 64
static uint64_t watch[MAX_WATCH];
static int n_watch;
/* the block executed last (one vCPU) */
static struct tally *prev;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static const char *path;

static void on_exec(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    struct tally *t = udata;
    t->execs++;
    if (t->watched && prev) {
        uint64_t from = prev->vaddr;
        unsigned h = (unsigned)((from >> 1) ^ (t->vaddr >> 1) * 31u) % BUCKETS;
        struct edge *e = edges[h];
        while (e && !(e->from == from && e->to == t->vaddr)) {
            e = e->next;
        }
        if (!e) {
            e = calloc(1, sizeof *e);
            e->from = from;
            e->to = t->vaddr;
            pthread_mutex_lock(&lock);
            e->next = edges[h];
            edges[h] = e;
            pthread_mutex_unlock(&lock);
        }
        e->n++;
    }
    prev = t;
}

static void on_tb(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    uint64_t pc = qemu_plugin_tb_vaddr(tb);
    uint64_t n = qemu_plugin_tb_n_insns(tb);
    unsigned h = (unsigned)((pc >> 1) ^ (pc >> 17)) % BUCKETS;
    pthread_mutex_lock(&lock);
    struct tally *t = table[h];
    while (t && !(t->vaddr == pc && t->n_insns == n)) {
        t = t->next;
    }
    if (!t) {
        t = calloc(1, sizeof *t);
        t->vaddr = pc;
        t->n_insns = n;
        for (int i = 0; i < n_watch; i++) {
            t->watched |= watch[i] == pc;
        }
        t->next = table[h];
        table[h] = t;
    }
    pthread_mutex_unlock(&lock);
    qemu_plugin_register_vcpu_tb_exec_cb(tb, on_exec, QEMU_PLUGIN_CB_NO_REGS, t);
}

static void dump(void)
{
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    FILE *f = fopen(tmp, "w");
    if (!f) {
        return;
    }
    uint64_t total = 0;
    pthread_mutex_lock(&lock);
    for (unsigned h = 0; h < BUCKETS; h++) {
        for (struct tally *t = table[h]; t; t = t->next) {
            total += t->n_insns * t->execs;
        }
    }
    fprintf(f, "total %llu\n", (unsigned long long)total);
    for (unsigned h = 0; h < BUCKETS; h++) {
        for (struct tally *t = table[h]; t; t = t->next) {
            if (t->execs) {
                fprintf(f, "%llx %llu %llu\n", (unsigned long long)t->vaddr,
                        (unsigned long long)t->n_insns, (unsigned long long)t->execs);
            }
        }
    }
    for (unsigned h = 0; h < BUCKETS; h++) {
        for (struct edge *e = edges[h]; e; e = e->next) {
            fprintf(f, "edge %llx %llx %llu\n", (unsigned long long)e->from,
                    (unsigned long long)e->to, (unsigned long long)e->n);
        }
    }
    pthread_mutex_unlock(&lock);
    fclose(f);
    rename(tmp, path);
}

static void *writer(void *arg)
{
    (void)arg;
    for (;;) {
        sleep(1);
        dump();
    }
    return NULL;
}

static void on_plugin_exit(qemu_plugin_id_t id, void *udata)
{
    (void)id;
    (void)udata;
    dump();
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id,
                                                               const qemu_info_t *info,
                                                               int argc, char **argv)
{
    (void)info;
    for (int i = 0; i < argc; i++) {
        if (strncmp(argv[i], "out=", 4) == 0) {
            path = strdup(argv[i] + 4);
        } else if (strncmp(argv[i], "watch=", 6) == 0 && n_watch < MAX_WATCH) {
            watch[n_watch++] = strtoull(argv[i] + 6, NULL, 16) & ~1ull;
        }
    }
    if (!path) {
        fprintf(stderr, "insn_profile: need out=FILE\n");
        return -1;
    }
    pthread_t t;
    if (pthread_create(&t, NULL, writer, NULL) != 0) {
        return -1;
    }
    pthread_detach(t);
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_tb);
    qemu_plugin_register_atexit_cb(id, on_plugin_exit, NULL);
    return 0;
}
