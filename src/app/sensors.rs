//! The sensor task: sample every sensor, apply the fault policy, run the lag filters and fold
//! the model (the slow path). Publishes the fold and the move gate to the command path.

use super::{Comp, Shared};
use embassy_futures::select::select;
use embassy_time::{Duration, Instant, Timer};
use nanocal_compensator::fault::MAX_CHANNELS;
use nanocal_compensator::proxy::Gate;
use nanocal_compensator::sensor::{self, Chip, SensorFault, FRAME_LEN};
use nanocal_model::LagBank;

/// A bus that clocks a frame in and out of the sensor behind chip-select `cs`.
#[allow(async_fn_in_trait)]
pub trait SensorBus {
    /// Full-duplex transfer: `frame` is sent and replaced by the bytes received.
    async fn transfer(&mut self, cs: u8, frame: &mut [u8; FRAME_LEN]) -> Result<(), SensorFault>;
}

/// Run the sensor task for the chips on chip-selects `0..chips.len()`.
pub async fn sensors<B: SensorBus>(mut bus: B, chips: &[Chip], period: Duration, sh: &Shared) -> ! {
    let chips = &chips[..chips.len().min(MAX_CHANNELS)];
    for (cs, &chip) in chips.iter().enumerate() {
        for mut f in sensor::config_frames(chip) {
            if bus.transfer(cs as u8, &mut f).await.is_err() {
                warn!("sensor {=usize}: configuration not acknowledged", cs);
            }
        }
    }
    let mut lags: Option<(u32, LagBank)> = None;
    let mut last = Instant::now();
    loop {
        select(Timer::after(period), sh.refold.wait()).await;
        let now = Instant::now();
        let now_ms = now.as_millis() as u32;
        let dt_s = (now - last).as_micros() as f64 * 1e-6;
        last = now;
        // sample outside any lock
        let mut readings = [Err(SensorFault::NoResponse); MAX_CHANNELS];
        for (cs, &chip) in chips.iter().enumerate() {
            let mut f = sensor::read_frame(chip);
            readings[cs] = match bus.transfer(cs as u8, &mut f).await {
                Ok(()) => sensor::decode(chip, &f).map(|r| r.temp_c),
                Err(e) => Err(e),
            };
        }
        let update = sh.model.lock(|m| {
            let mut m = m.borrow_mut();
            let m = &mut *m;
            for (cs, r) in readings.iter().enumerate().take(chips.len()) {
                m.faults.update(cs, *r, now_ms);
            }
            for (i, ch) in m.faults.channels.iter().enumerate() {
                if let Some(t) = ch.value_c() {
                    m.slow.temps_c[i] = f64::from(t);
                }
            }
            let model = m.model.as_ref()?;
            let bank = match &mut lags {
                Some((g, bank)) if *g == m.generation => bank,
                _ => &mut lags.insert((m.generation, LagBank::new(model.lags()))).1,
            };
            bank.update(&m.slow.temps_c, dt_s, &mut m.slow.lagged_c);
            let comp = Comp::new(model, &m.slow);
            m.slow_outside = comp.fold.slow_outside_envelope();
            m.folds = m.folds.wrapping_add(1);
            let blocked = m.faults.blocks_moves(model.temps());
            Some((comp, blocked))
        });
        if let Some((comp, blocked)) = update {
            sh.core.lock(|c| {
                let mut c = c.borrow_mut();
                c.comp = Some(comp);
                c.proxy.gate = if blocked {
                    Gate::SensorFault
                } else {
                    Gate::Open
                };
            });
        }
    }
}
