# Independent encoder of the documented layouts (struct + zlib.crc32), emitting the Rust byte
# arrays of tests/golden/bytes.rs: python3 tests/golden/encode.py > tests/golden/bytes.rs
import struct, zlib

def frame(kind, seq, payload):
    hdr = bytes([kind, seq]) + struct.pack('<H', len(payload))
    body = hdr + payload
    return bytes([0xA7, 0x5C]) + body + struct.pack('<I', zlib.crc32(body))

def settings(baud, sensors, mains, period, unit, axes, aux, fold_ms=5000, version=6, n_cs=16,
             stale_k=3.0, extrapolation_c=0.1, allow_other_stage=0, follow=(0, 10000, 0)):
    b = b'NCST' + bytes([version]) + struct.pack('<I', baud)
    for i in range(n_cs):
        kind, a, rr, r0 = sensors.get(i, (0, 0, 0.0, 0.0))
        b += bytes([kind, a]) + struct.pack('<ff', rr, r0)
    # layouts 1 to 4: the stage unit (0 µm, 1 mm, 2 nm); layout 5: reserved, 0
    b += bytes([mains]) + struct.pack('<H', period) + bytes([unit if version <= 4 else 0])
    for name in axes:
        b += bytes([len(name)]) + name + bytes(8 - len(name))
    for kind, ch, sc, off in aux:
        b += bytes([kind, ch]) + struct.pack('<ff', sc, off)
    if version >= 3:
        b += struct.pack('<H', fold_ms)
    if version >= 4:
        b += struct.pack('<ff', stale_k, extrapolation_c)
    if version >= 6:
        b += bytes([allow_other_stage])
        # held targets follow the model: threshold nm, interval ms, step nm
        b += struct.pack('<HHH', *follow)
    return b + struct.pack('<I', zlib.crc32(b))

def status():
    # protocol 5: model_crc32 at offset 6 (protocol 4 had one reserved byte 0xFF there)
    # flags: MODEL, EXTRAPOLATING, HOST_CONNECTED, MOVE_FOLD, MODEL_STALE, STAGE_MISMATCH (bit 13)
    b = struct.pack('<H', 0x3A09) + struct.pack('<I', 0x00030001) + struct.pack('<I', 0x89ABCDEF) + struct.pack('<I', 41)
    temps = [20.5, 21.25, -1.5, 0.0] + [0.0] * 12
    b += struct.pack('<16f', *temps)
    b += bytes([0x00, 0x11, 0x62, 0x04] + [0] * 12)
    b += bytes([4]) + struct.pack('<I', 0x10)
    b += struct.pack('<3d', 0.125, -0.5, 0.0)
    b += struct.pack('<7I', 100, 50, 2, 30, 1, 1, 42)
    b += struct.pack('<i', 9008) + bytes([8]) + struct.pack('<I', 123456)
    b += b'0123456789AB' + bytes([4, 5]) + struct.pack('<3I', 250, 0, 3)
    b += struct.pack('<4f', 1013.25, 0.0, 0.0, 0.0) + bytes([0, 4, 4, 4])
    # protocol 6: the model-stale check (flag bit 12 above, LED state 5 above)
    b += bytes([0x02]) + struct.pack('<I', 100000)
    b += struct.pack('<3f', 0.25, -0.125, 0.0) + struct.pack('<3f', 0.09375, 0.0, 0.0)
    b += struct.pack('<f', 0.5)
    # protocol 7: the provenance check: stage 4 (mismatch allowed), the two serials
    b += bytes([4])
    b += bytes([10]) + b'0116044408'.ljust(24, b'\0')
    b += bytes([10]) + b'0116044999'.ljust(24, b'\0')
    # protocol 8: following's counters (re-issues accepted, refused)
    b += struct.pack('<2I', 17, 3)
    assert len(b) == 298, len(b)
    return b

def rust(name, b, doc):
    out = f"/// {doc}\nconst {name}: [u8; {len(b)}] = [\n"
    for i in range(0, len(b), 16):
        out += "    " + ", ".join(f"0x{x:02X}" for x in b[i:i + 16]) + ",\n"
    return out + "];\n\n"

default_settings = settings(115200, {i: (1, 3, 0.0, 0.0) for i in range(4)}, 50, 250, 0,
                            [b'1', b'2', b'3'], [(0, 0, 0.0, 0.0)] * 4)
custom_args = (57600, {0: (1, 3, 0.0, 0.0), 1: (1, 7, 0.0, 0.0), 2: (2, 3, 430.0, 100.0),
                       3: (2, 4, 4300.0, 1000.0)}, 60, 500, 1, [b'X', b'Y', b'3'],
               [(1, 0, 0.0, 0.0), (2, 0, 0.01, -20.48), (0, 0, 0.0, 0.0), (0, 0, 0.0, 0.0)])
custom_settings = settings(*custom_args, fold_ms=8000, stale_k=2.5, extrapolation_c=0.25,
                           allow_other_stage=1, follow=(5, 2000, 20))
# the same settings as a version 5 record (no allow_other_stage, no following), as a firmware before layout 6 stored them
custom_settings_v5 = settings(*custom_args, fold_ms=8000, stale_k=2.5, extrapolation_c=0.25, version=5)
# the same settings as a version 4 record (stage unit mm, never applied), as a firmware before layout 5 stored them
custom_settings_v4 = settings(*custom_args, fold_ms=8000, stale_k=2.5, extrapolation_c=0.25, version=4)
# the same settings as a version 3 record (no stale check), as a firmware before layout 4 stored them
custom_settings_v3 = settings(*custom_args, fold_ms=8000, version=3)
# the same settings as a version 2 record (no fold period), as a firmware before layout 3 stored them
custom_settings_v2 = settings(*custom_args, version=2)
assert len(default_settings) == 261
assert len(custom_settings_v5) == 254
assert len(custom_settings_v4) == 254
assert len(custom_settings_v3) == 246
assert len(custom_settings_v2) == 244

hello = struct.pack('<HHH', 8, 4, 256) + bytes([5]) + b'0.1.0' + bytes(range(12)) + bytes([8]) + bytes([19]) + b'src/bin/stm32.rs:42'
items = [
    ("STATUS_BYTES", status(), "The status of `status()` alone (298 bytes)."),
    ("SETTINGS_DEFAULT", default_settings, "`Settings::default()` (261 bytes, layout 6)."),
    ("SETTINGS_CUSTOM", custom_settings, "The settings of `custom_settings()` (fold period 8 s, k 2.5, margin 0.25 °C, other stages allowed, following 5 nm / 2 s / 20 nm)."),
    ("SETTINGS_CUSTOM_V5", custom_settings_v5, "`custom_settings()` as a layout 5 record (no allow_other_stage, no following, 254 bytes)."),
    ("SETTINGS_CUSTOM_V4", custom_settings_v4, "`custom_settings()` as a layout 4 record (stage unit mm, 254 bytes)."),
    ("SETTINGS_CUSTOM_V3", custom_settings_v3, "`custom_settings()` as a layout 3 record (no stale check, 246 bytes)."),
    ("SETTINGS_CUSTOM_V2", custom_settings_v2, "`custom_settings()` as a layout 2 record (no fold period, 244 bytes)."),
    ("REQ_HELLO", frame(0x01, 1, b''), "HELLO, seq 1."),
    ("REQ_STATUS", frame(0x02, 2, b''), "STATUS, seq 2."),
    ("REQ_UPLOAD_BEGIN", frame(0x10, 3, struct.pack('<IIH', 1234, 0xDEADBEEF, 2)), "UPLOAD_BEGIN 1234 bytes, CRC DEADBEEFh, format 2, seq 3."),
    ("REQ_UPLOAD_CHUNK", frame(0x11, 4, struct.pack('<I', 256) + bytes([1, 2, 3, 4])), "UPLOAD_CHUNK at 256 of 01 02 03 04, seq 4."),
    ("REQ_UPLOAD_COMMIT", frame(0x12, 5, b''), "UPLOAD_COMMIT, seq 5."),
    ("REQ_UPLOAD_ABORT", frame(0x13, 6, b''), "UPLOAD_ABORT, seq 6."),
    ("REQ_SET_KMZ", frame(0x20, 7, struct.pack('<6d', 250.0, 0.0, 0.0, 249.9, 0.0, 0.0)), "SET_KMZ q = (250, 0, 0), x = (249.9, 0, 0), seq 7."),
    ("REQ_BYPASS", frame(0x21, 8, bytes([1])), "BYPASS on, seq 8."),
    ("REQ_CONFIG_GET", frame(0x30, 9, b''), "CONFIG_GET, seq 9."),
    ("REQ_CONFIG_SET", frame(0x31, 10, custom_settings), "CONFIG_SET of `custom_settings()`, seq 10."),
    ("REQ_RESET", frame(0x32, 11, b''), "RESET, seq 11."),
    ("REQ_DEBUG_HANG", frame(0x7E, 12, b''), "DEBUG_HANG, seq 12."),
    ("REP_HELLO", frame(0x81, 1, bytes([0]) + hello), "HELLO reply: protocol 8, blob format 4, chunk 256, firmware \"0.1.0\", UID 00..0B, panic at src/bin/stm32.rs:42."),
    ("REP_STATUS", frame(0x82, 2, bytes([0]) + status()), "STATUS reply with `status()`."),
    ("REP_UPLOAD_BEGIN", frame(0x90, 3, bytes([0])), "UPLOAD_BEGIN reply: ok."),
    ("REP_UPLOAD_CHUNK", frame(0x91, 4, bytes([0]) + struct.pack('<I', 260)), "UPLOAD_CHUNK reply: 260 bytes received."),
    ("REP_UPLOAD_COMMIT", frame(0x92, 5, bytes([0]) + struct.pack('<III', 0x00030001, 0x89ABCDEF, 3)), "UPLOAD_COMMIT reply: model 00030001h, blob CRC 89ABCDEFh, 3 uploads accepted."),
    ("REP_UPLOAD_ABORT", frame(0x93, 6, bytes([0])), "UPLOAD_ABORT reply: ok."),
    ("REP_SET_KMZ", frame(0xA0, 7, bytes([0]) + struct.pack('<3dB', 0.125, 0.0, 0.0, 1)), "SET_KMZ reply: λ_KMZ (0.125, 0, 0), stored."),
    ("REP_BYPASS", frame(0xA1, 8, bytes([0])), "BYPASS reply: ok."),
    ("REP_CONFIG_GET", frame(0xB0, 9, bytes([0]) + custom_settings), "CONFIG_GET reply with `custom_settings()`."),
    ("REP_CONFIG_SET", frame(0xB1, 10, bytes([0])), "CONFIG_SET reply: ok."),
    ("REP_RESET", frame(0xB2, 11, bytes([0])), "RESET reply: ok."),
    ("REP_COMMIT_INPUT", frame(0x92, 5, bytes([24, 0x20])), "UPLOAD_COMMIT refused: input 0 has no source (24, 20h)."),
    ("REP_COMMIT_CRC", frame(0x92, 5, bytes([8])), "UPLOAD_COMMIT refused: whole-blob CRC mismatch (8)."),
    ("REP_UNKNOWN_KIND", frame(0xFE, 12, bytes([23])), "DEBUG_HANG refused as unknown (a board without it), seq 12."),
    ("BUS_SPI_REQUEST", bytes([0xA5, 1, 3, 2, 2, 0x0C, 0xFF]), "SPI on chip-select 3: 0Ch FFh out, 2 bytes in."),
    ("BUS_SPI_REPLY", bytes([0x5A, 1, 3, 0, 2, 0x00, 0x8A]), "Its reply: done, 00h 8Ah."),
    ("BUS_I2C_NACK", bytes([0x5A, 2, 0x5C, 1, 0]), "An I2C reply: address 5Ch not acknowledged."),
    ("BUS_ADC_NO_ANSWER", bytes([0x5A, 3, 0, 0xFF, 0]), "An ADC reply: nothing answered."),
]
print("// Generated by tests/golden/encode.py, an independent encoder of the documented layouts (Python")
print("// `struct` and `zlib.crc32`), not by this crate. Regenerate only when the bytes are meant to")
print("// change, together with a protocol/layout version bump.\n")
for name, b, doc in items:
    print(rust(name, b, doc), end="")
