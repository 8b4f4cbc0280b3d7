//! The proxy and the simulated controller in one process, on a hand-driven clock: a host's
//! bytes go through `Proxy::host_bytes`, what the proxy sends reaches the `Controller` at once,
//! its replies come back through `Proxy::stage_bytes`, and time advances only when told — the
//! same loop the firmware's links run, without sockets or threads.
#![allow(dead_code)]

use nanocal::virtual_bench::{Config, Controller, Event, IdealPlant, ManualClock};
use nanocal_compensator::proxy::{FoldCorrector, Output, Proxy, REPLY_TIMEOUT_MS};
use nanocal_model::{Model, SlowInputs};
use std::sync::Arc;

/// Slow inputs with these temperatures.
pub fn slow(temps: &[f64]) -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[..temps.len()].copy_from_slice(temps);
    s
}

/// The proxy between a host and a simulated controller.
pub struct Rig {
    pub proxy: Proxy,
    pub comp: Option<FoldCorrector>,
    pub ctl: Controller,
    pub clock: ManualClock,
    pub now_ms: u32,
    out: Output,
    /// Everything the host received.
    pub host_rx: Vec<u8>,
    /// Controller bytes not yet given to the proxy.
    stage_rx: Vec<u8>,
    /// The controller is not running (rebooting, its cable out): what the proxy sends it is
    /// lost, and it answers nothing.
    pub silent: bool,
}

impl Rig {
    /// A rig with `cfg`'s controller and `model` folded at `temps` (no model: `None`).
    pub fn new(cfg: Config, model: Option<&Model>, temps: &[f64]) -> Self {
        let clock = ManualClock::new();
        let start: Vec<f64> = cfg.axes.iter().map(|a| a.start).collect();
        let ctl = Controller::new(
            cfg,
            Box::new(IdealPlant::new(&start)),
            Arc::new(clock.clone()),
        );
        Self {
            proxy: Proxy::default(),
            comp: model.map(|m| FoldCorrector::new(m, &slow(temps))),
            ctl,
            clock,
            now_ms: 1,
            out: Output::new(),
            host_rx: vec![],
            stage_rx: vec![],
            silent: false,
        }
    }

    fn route(&mut self) {
        self.host_rx.extend_from_slice(self.out.to_host.as_bytes());
        if !self.out.to_stage.is_empty() && !self.silent {
            let reply = self.ctl.input(self.out.to_stage.as_bytes());
            self.stage_rx.extend_from_slice(&reply);
        }
        self.out.clear();
    }

    /// Give the proxy the controller's pending replies and everything that follows from them.
    fn pump(&mut self) {
        loop {
            let mut progress = false;
            while !self.stage_rx.is_empty() {
                let bytes = std::mem::take(&mut self.stage_rx);
                let used =
                    self.proxy
                        .stage_bytes(self.comp.as_ref(), &bytes, self.now_ms, &mut self.out);
                // replies that arrive meanwhile queue behind the rest
                let mut rest = bytes[used..].to_vec();
                self.route();
                rest.extend_from_slice(&self.stage_rx);
                self.stage_rx = rest;
                progress |= used > 0;
                if used == 0 {
                    break;
                }
            }
            while self.proxy.has_work() {
                self.proxy
                    .host_bytes(self.comp.as_ref(), &[], self.now_ms, &mut self.out);
                self.route();
                progress = true;
            }
            if !progress && self.stage_rx.is_empty() {
                return;
            }
        }
    }

    /// Host bytes in; returns what the host received meanwhile.
    pub fn host(&mut self, bytes: &[u8]) -> Vec<u8> {
        let start = self.host_rx.len();
        let mut i = 0;
        let mut idle = 0;
        while i < bytes.len() {
            let used =
                self.proxy
                    .host_bytes(self.comp.as_ref(), &bytes[i..], self.now_ms, &mut self.out);
            i += used;
            let empty = self.out.is_empty();
            self.route();
            self.pump();
            if used == 0 && empty {
                // the proxy waits for the controller: let time pass
                idle += 1;
                assert!(idle < 10_000, "the proxy never took the host's bytes");
                self.wait_ms(50);
            }
        }
        self.pump();
        self.host_rx[start..].to_vec()
    }

    /// A host line (LF appended); returns what the host received meanwhile.
    pub fn line(&mut self, l: &str) -> String {
        text(&self.host(format!("{l}\n").as_bytes()))
    }

    /// Let `ms` pass (the proxy's timeout, the controller's motions).
    pub fn wait_ms(&mut self, ms: u32) {
        self.now_ms = self.now_ms.wrapping_add(ms);
        self.clock.advance(f64::from(ms) * 1e-3);
        self.proxy
            .poll(self.comp.as_ref(), self.now_ms, &mut self.out);
        self.route();
        self.pump();
    }

    /// Let `ms` pass with held targets following the model: the stage link's tick every
    /// `tick_ms` (a poll, then `follow_tick`, and `follow_tick` again after the controller's
    /// replies), as the firmware runs it while following is armed.
    pub fn follow_for_ms(&mut self, ms: u32, tick_ms: u32) {
        let mut left = ms;
        while left > 0 {
            let d = left.min(tick_ms);
            left -= d;
            self.wait_ms(d);
            // (the firmware ticks again once the controller's replies are in: a check that
            // cleared is followed by its re-issue at once)
            for _ in 0..2 {
                self.proxy
                    .follow_tick(self.comp.as_ref(), self.now_ms, &mut self.out);
                self.route();
                self.pump();
            }
        }
    }

    /// Let the proxy's reply timeout pass, so queries the controller never answered are
    /// given up (what the firmware's stage link does by polling).
    pub fn settle(&mut self) {
        if self.proxy.in_flight() > 0 || self.proxy.holding() {
            self.wait_ms(REPLY_TIMEOUT_MS + 10);
        }
    }

    /// The controller's events since the last call.
    pub fn events(&mut self) -> Vec<Event> {
        self.ctl.take_events()
    }

    /// What the controller received since the last call.
    pub fn received(&mut self) -> Vec<String> {
        self.ctl.take_received()
    }
}

/// Bytes as text (cp1252 → chars, as PIPython decodes them).
pub fn text(b: &[u8]) -> String {
    b.iter().map(|&c| c as char).collect()
}

/// A controller that knows every command the proxy treats (the union of the E-727 and C-867
/// sets), with `axes` axes, servo on and referenced.
pub fn everything(axes: usize) -> Config {
    let mut cfg = Config::c867(axes, "µm").ready();
    for c in Config::e727(axes).commands {
        if !cfg.commands.contains(&c) {
            cfg.commands.push(c);
        }
    }
    for c in ["MVE", "WAV", "WTR", "MAC"] {
        if !cfg.commands.contains(&c) {
            cfg.commands.push(c);
        }
    }
    cfg
}

/// The value of `axis` in an `axis=value` reply.
pub fn value(reply: &str, axis: &str) -> f64 {
    reply
        .lines()
        .find_map(|l| {
            let (a, v) = l.trim().split_once('=')?;
            (a.split_whitespace().last() == Some(axis)).then(|| v.trim().parse().ok())?
        })
        .unwrap_or_else(|| panic!("no {axis}= in {reply:?}"))
}
