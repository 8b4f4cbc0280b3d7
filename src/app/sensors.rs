//! The sensor task: drive every amplifier at register level (configure, wait for the first
//! conversion, dump and check its registers every cycle), read the aux sources (barometer,
//! ADC), apply the fault policy, average the readings over the fold period, and once a fold
//! period run the lag filters on the averages and fold the model (the slow path,
//! [`nanocal_compensator::slow_average`]; a new model is folded at once). Publishes the fold
//! and the move gate to the command path.
//!
//! Beside that slow cycle, and sharing the buses with it one transaction at a time, the task
//! samples the model's fast inputs (a force on an ADC channel) every [`FAST_PERIOD_MS`]: the
//! command path corrects each command with the latest sample, and refuses it when that sample
//! failed or is older than [`fast_stale_ms`] (paper 001 §VI: forces "have imperatively to be
//! compensated in real-time").
//!
//! Every bus transaction has a timeout, so a hung bus is a sensor fault, never a hung task;
//! channels without a reading in a cycle have their hold time checked all the same.

use super::{now_ms, Comp, Shared};
use core::sync::atomic::Ordering;
use embassy_futures::join::join;
use embassy_futures::select::{select3, Either3};
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_time::{with_timeout, Duration, Timer};
use nanocal_compensator::fault::{ChannelState, MAX_CHANNELS};
use nanocal_compensator::inputs;
use nanocal_compensator::lps22hb;
use nanocal_compensator::proxy::Gate;
use nanocal_compensator::sensor::{Driver, Outcome, SensorFault, MAX_TXN};
use nanocal_compensator::slow_average::SlowAverage;
use nanocal_compensator::stale;
use nanocal_interface::settings::{AuxSource, Settings};
use nanocal_model::{LagBank, MAX_AUX};

/// Times the barometer is asked at start-up before it counts as absent.
const PROBES: usize = 3;

/// Sampling period of the fast inputs, ms.
pub const FAST_PERIOD_MS: u64 = 10;

/// With no fast input in service, the fast sampler looks again this often (besides on every
/// model release), ms.
const IDLE_RECHECK_MS: u64 = 1_000;

/// Oldest fast sample a command may be corrected with, ms: five sampling periods, plus one bus
/// transaction's timeout (the sampler may wait for the slow cycle's transaction in progress).
pub fn fast_stale_ms(timeout: Duration) -> u32 {
    5 * FAST_PERIOD_MS as u32 + timeout.as_millis() as u32
}

/// The buses, shared by the slow cycle and the fast sampler one transaction at a time.
type SharedBus<B> = Mutex<NoopRawMutex, B>;

/// The buses the inputs hang on.
#[allow(async_fn_in_trait)]
pub trait InputBus {
    /// One SPI transaction with chip-select `cs` low for all of `buf` (sent, and replaced by
    /// the bytes received).
    async fn spi(&mut self, cs: u8, buf: &mut [u8]) -> Result<(), ()>;
    /// An I2C write of `w` then a read into `r` (repeated start) at 7-bit address `addr`.
    async fn i2c(&mut self, addr: u8, w: &[u8], r: &mut [u8]) -> Result<(), ()>;
    /// One ADC conversion of `channel` (12-bit code).
    async fn adc(&mut self, channel: u8) -> Result<u16, ()>;
    /// ADC channels the board has (bit per channel).
    fn adc_channels(&self) -> u32;
    /// Chip-select lines wired for temperature amplifiers (`0..n`).
    fn chip_selects(&self) -> u8;
}

/// The source of every aux input: the model's (see [`inputs::aux_source`]) while a model is in
/// service, else the settings' mapping (for the status report).
fn aux_sources(sh: &Shared, settings: &Settings) -> [AuxSource; MAX_AUX] {
    sh.model.lock(|m| {
        let m = m.borrow();
        let mut src = settings.aux;
        if let Some(model) = &m.model {
            for (n, s) in src.iter_mut().enumerate() {
                *s = if n < model.aux() {
                    inputs::aux_source(settings, model, n)
                } else {
                    AuxSource::None
                };
            }
        }
        src
    })
}

fn drivers(s: &Settings) -> [Option<Driver>; MAX_CHANNELS] {
    let mut d = [None; MAX_CHANNELS];
    for (i, c) in s.sensors.iter().enumerate().take(MAX_CHANNELS) {
        d[i] = c.map(|chip| Driver::new(chip, s.mains));
    }
    d
}

async fn run_driver<B: InputBus>(
    d: &mut Driver,
    bus: &SharedBus<B>,
    cs: u8,
    now: u32,
    timeout: Duration,
) -> Option<Result<f32, SensorFault>> {
    let mut buf = [0u8; MAX_TXN];
    for _ in 0..4 {
        let txn = d.next(now)?;
        let n = d.fill(txn, &mut buf);
        let rx = match with_timeout(timeout, bus.lock().await.spi(cs, &mut buf[..n])).await {
            Ok(Ok(())) => Ok(&buf[..n]),
            _ => Err(SensorFault::NoResponse),
        };
        match d.complete(txn, rx, now) {
            Outcome::Continue => continue,
            Outcome::Waiting => return None,
            Outcome::Reading(r) => return Some(r.map(|x| x.temp_c)),
        }
    }
    None
}

/// The barometer's state.
#[derive(Default)]
struct Baro {
    ever_converted: bool,
}

impl Baro {
    /// Whether the barometer answers, asked up to [`PROBES`] times: a bus a slave holds at
    /// power-up fails the first transaction, which frees it (the board's bus recovery).
    async fn probe<B: InputBus>(bus: &SharedBus<B>, timeout: Duration) -> bool {
        for _ in 0..PROBES {
            let mut id = [0u8; 1];
            let mut bus = bus.lock().await;
            let answered = matches!(
                with_timeout(
                    timeout,
                    bus.i2c(lps22hb::ADDRESS, &[lps22hb::WHO_AM_I], &mut id)
                )
                .await,
                Ok(Ok(()))
            );
            if answered {
                return id[0] == lps22hb::ID;
            }
        }
        false
    }

    async fn read<B: InputBus>(
        &mut self,
        bus: &SharedBus<B>,
        timeout: Duration,
    ) -> Option<Result<f32, SensorFault>> {
        let a = lps22hb::ADDRESS;
        let mut bus = bus.lock().await;
        let mut ctrl = [0u8; 1];
        if with_timeout(timeout, bus.i2c(a, &[lps22hb::CTRL_REG1], &mut ctrl))
            .await
            .ok()?
            .is_err()
        {
            return Some(Err(SensorFault::NoResponse));
        }
        if ctrl[0] != lps22hb::CTRL_REG1_VALUE {
            // power-on default (or it was reset): start conversions and wait for the first
            self.ever_converted = false;
            let w = [lps22hb::CTRL_REG1, lps22hb::CTRL_REG1_VALUE];
            let _ = with_timeout(timeout, bus.i2c(a, &w, &mut [])).await;
            return None;
        }
        let mut burst = [0u8; lps22hb::BURST];
        match with_timeout(timeout, bus.i2c(a, &[lps22hb::STATUS], &mut burst)).await {
            Ok(Ok(())) => {}
            _ => return Some(Err(SensorFault::NoResponse)),
        }
        let v = lps22hb::decode(&burst, self.ever_converted);
        self.ever_converted |= burst[0] & 0x01 != 0;
        match v {
            Some(hpa) => Some(Ok(hpa)),
            None if !self.ever_converted => None,
            None => Some(Err(SensorFault::Implausible)),
        }
    }
}

/// Run the sensor task. `timeout` bounds every bus transaction.
pub async fn sensors<B: InputBus>(bus: B, timeout: Duration, sh: &Shared) -> ! {
    let bus = Mutex::new(bus);
    sh.core
        .lock(|c| c.borrow_mut().fast_stale_ms = fast_stale_ms(timeout));
    join(
        slow_cycle(&bus, timeout, sh),
        fast_inputs(&bus, timeout, sh),
    )
    .await;
    unreachable!()
}

/// ADC channel and scaling of every fast input of the model in service (`None`: not fast, or
/// no model).
fn fast_sources(sh: &Shared) -> [Option<AuxSource>; MAX_AUX] {
    // the settings are borrowed, not copied: this runs at every wake-up of the fast sampler,
    // and a copy of the settings (292 B) was ≈ 1,000 guest instructions each time
    sh.settings.lock(|settings| {
        let settings = settings.borrow();
        sh.model.lock(|m| {
            let m = m.borrow();
            let mut src = [None; MAX_AUX];
            if let Some(model) = m.in_service() {
                for (n, s) in src.iter_mut().enumerate().take(model.aux()) {
                    if model.is_fast(n) {
                        *s = Some(inputs::aux_source(&settings, model, n));
                    }
                }
            }
            src
        })
    })
}

/// Whether the model in service has a fast input ([`fast_sources`] has one): the idle fast
/// sampler asks this at every wake-up, without building (and moving, 48 B at a time) the
/// sources themselves.
fn any_fast(sh: &Shared) -> bool {
    sh.model.lock(|m| {
        let m = m.borrow();
        m.in_service()
            .is_some_and(|model| (0..model.aux().min(MAX_AUX)).any(|n| model.is_fast(n)))
    })
}

/// One reading of an aux source: air pressure from the barometer, a force from its ADC channel
/// (`None`: no reading this time, e.g. the barometer's first conversion is not done).
async fn read_aux<B: InputBus>(
    src: AuxSource,
    baro: &mut Baro,
    bus: &SharedBus<B>,
    timeout: Duration,
) -> Option<Result<f32, SensorFault>> {
    match src {
        AuxSource::None => None,
        AuxSource::AirPressure => baro.read(bus, timeout).await,
        AuxSource::Force {
            channel,
            scale_n_per_count,
            offset_n,
        } => Some(
            match with_timeout(timeout, bus.lock().await.adc(channel)).await {
                Ok(Ok(code)) => Ok(offset_n + scale_n_per_count * f32::from(code)),
                _ => Err(SensorFault::NoResponse),
            },
        ),
    }
}

/// Sample the model's fast inputs every [`FAST_PERIOD_MS`] into the command path's
/// [`inputs::FastSamples`]. With no fast input in the model in service the sampler sleeps until
/// a model is released (or [`IDLE_RECHECK_MS`] pass): a wake-up every 10 ms for nothing costs
/// power on the board and most of the emulated time of a long virtual-bench campaign.
async fn fast_inputs<B: InputBus>(bus: &SharedBus<B>, timeout: Duration, sh: &Shared) -> ! {
    let mut baro = Baro::default();
    loop {
        if !any_fast(sh) {
            let _ = with_timeout(
                Duration::from_millis(IDLE_RECHECK_MS),
                sh.model_released.wait(),
            )
            .await;
            continue;
        }
        Timer::after_millis(FAST_PERIOD_MS).await;
        for (n, src) in fast_sources(sh).iter().enumerate() {
            let Some(src) = *src else { continue };
            let r = read_aux(src, &mut baro, bus, timeout)
                .await
                .unwrap_or(Err(SensorFault::NoResponse));
            let now = now_ms();
            sh.core.lock(|c| c.borrow_mut().fast.record(n, r, now));
        }
    }
}

/// The slow cycle: temperatures, aux inputs, fault policy; once a fold period the averages,
/// lag filters, fold.
async fn slow_cycle<B: InputBus>(bus: &SharedBus<B>, timeout: Duration, sh: &Shared) -> ! {
    let mut settings = sh.settings.lock(|s| *s.borrow());
    let mut drv = drivers(&settings);
    let barometer = Baro::probe(bus, timeout).await;
    let (adc_channels, chip_selects) = {
        let bus = bus.lock().await;
        (bus.adc_channels(), bus.chip_selects())
    };
    sh.board.lock(|b| {
        let mut b = b.borrow_mut();
        b.barometer = barometer;
        b.adc_channels = adc_channels;
        b.chip_selects = chip_selects;
    });
    info!("barometer: {=bool}", barometer);
    let mut baro = Baro::default();
    let mut lags: Option<(u32, LagBank)> = None;
    let mut average = SlowAverage::new();
    loop {
        let period = Duration::from_millis(u64::from(settings.sample_period_ms));
        if let Either3::Third(()) = select3(
            Timer::after(period),
            sh.refold.wait(),
            sh.settings_changed.wait(),
        )
        .await
        {
            settings = sh.settings.lock(|s| *s.borrow());
            drv = drivers(&settings);
        }
        let ms = now_ms();
        // sample outside any lock
        let mut readings = [None; MAX_CHANNELS];
        let mut reconfigs = 0;
        for (cs, d) in drv.iter_mut().enumerate() {
            if let Some(d) = d {
                let before = d.reconfigurations;
                readings[cs] = run_driver(d, bus, cs as u8, ms, timeout).await;
                reconfigs += d.reconfigurations.wrapping_sub(before);
            }
        }
        // every aux input, the fast ones too (their status, and the slow reference values)
        let mut aux = [None; MAX_AUX];
        for (i, src) in aux_sources(sh, &settings).iter().enumerate() {
            aux[i] = read_aux(*src, &mut baro, bus, timeout).await;
        }
        let update = sh.model.lock(|m| {
            let mut m = m.borrow_mut();
            let m = &mut *m;
            m.sensor_reconfigs = m.sensor_reconfigs.wrapping_add(reconfigs);
            // this cycle's good readings join the fold period's averages (a reading the
            // policy accepted leaves its channel Ok, holding that reading)
            for (cs, r) in readings.iter().enumerate() {
                match r {
                    Some(r) => {
                        m.faults.update(cs, *r, ms);
                        let ch = &m.faults.channels[cs];
                        if r.is_ok() && ch.state == ChannelState::Ok {
                            average.add_temp(cs, ch.last_good_c);
                        }
                    }
                    None => m.faults.tick(cs, ms),
                }
            }
            for (i, r) in aux.iter().enumerate() {
                match r {
                    Some(r) => {
                        m.aux_faults.update(i, *r, ms);
                        let ch = &m.aux_faults.channels[i];
                        if r.is_ok() && ch.state == ChannelState::Ok {
                            average.add_aux(i, ch.last_good_c);
                        }
                    }
                    None => m.aux_faults.tick(i, ms),
                }
            }
            let fold_ms = u32::from(settings.fold_period_ms);
            let ready = m.in_service().map(|model| {
                m.faults.all_usable(model.temps()) && m.aux_faults.all_usable(model.aux())
            });
            // a model released and readable for the first time is folded at once
            let first = ready == Some(true)
                && !matches!(&lags, Some((g, _)) if *g == m.generation && m.inputs_ready);
            let dt_s = if average.due(ms, fold_ms) || first {
                // a channel without a reading in the period holds the policy's value
                let (t, a) = (&m.faults.channels, &m.aux_faults.channels);
                let held = |i: usize| match i.checked_sub(t.len()) {
                    None => t[i].value_c(),
                    Some(k) => a.get(k).and_then(|c| c.value_c()),
                };
                Some(average.fold(ms, &mut m.slow, held))
            } else {
                None
            };
            let model = m.model.as_ref()?;
            if m.pending {
                // received, not stored yet: no move may use it
                return Some(None);
            }
            let (temps, auxn) = (model.temps(), model.aux());
            let blocked = m.faults.blocks_moves(temps) || m.aux_faults.blocks_moves(auxn);
            if ready != Some(true) {
                // never prime lag filters or fold on inputs that were never read
                if !m.inputs_ready {
                    lags = None;
                }
                return Some(None);
            }
            let Some(dt_s) = dt_s else {
                // between folds the fold in force stands; a failed input closes the gate now,
                // the next fold opens it again
                return Some(Some((false, blocked)));
            };
            m.inputs_ready = true;
            let bank = match &mut lags {
                Some((g, bank)) if *g == m.generation => bank,
                // a new bank primes on these (valid) averages
                _ => &mut lags.insert((m.generation, LagBank::new(model.lags()))).1,
            };
            bank.update(&m.slow.temps_c, dt_s, &mut m.slow.lagged_c);
            m.folds = m.folds.wrapping_add(1);
            // the new fold is built where the command path reads it, under its lock (nothing
            // runs between this and the gate's update below): built here and moved there, the
            // corrector (≈ 3 KB) was copied twice a fold (issue 20 §5)
            m.slow_outside = sh.core.lock(|c| {
                let mut c = c.borrow_mut();
                let c = &mut *c;
                let comp = c.comp.insert(Comp::new(model, &m.slow));
                c.comp_fold = m.folds;
                c.folded_at_ms = ms;
                comp.fold.slow_outside_envelope()
            });
            // the model-stale check's envelope half: once a fold, never per command
            let excess_c = stale::envelope_excess_c(model, &m.slow);
            let was_stale = m.stale.is_stale();
            // logged when it rises, not at every fold while it stays out
            if m.stale.fold(excess_c, settings.extrapolation_c, ms) && !was_stale {
                warn!(
                    "model stale: a temperature left the envelope by {=f32} °C",
                    excess_c
                );
            }
            Some(Some((true, blocked)))
        });
        match update {
            Some(Some((folded, blocked))) => sh.core.lock(|c| {
                let mut c = c.borrow_mut();
                if folded {
                    c.proxy.gate = Gate::Open;
                }
                if blocked {
                    c.proxy.gate = Gate::SensorFault;
                }
            }),
            Some(None) => sh
                .core
                .lock(|c| c.borrow_mut().proxy.gate = Gate::SensorFault),
            None => {}
        }
        sh.sensor_beat_ms.store(now_ms(), Ordering::Relaxed);
    }
}
