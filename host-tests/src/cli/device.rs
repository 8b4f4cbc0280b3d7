//! `nanocal device upload|status|kmz|bypass|config|reset`: the inline compensator's management
//! channel.

use crate::device::{format_settings, format_status, uid_hex, Client};
use anyhow::{bail, Context};
use clap::Subcommand;
use nanocal_compensator::gcs::AxisId;
use nanocal_compensator::sensor::{Chip, Mains, TcType, Wires};
use nanocal_interface::settings::{AuxSource, Settings};
use std::path::PathBuf;

/// Device subcommands.
#[derive(Subcommand, Debug)]
pub enum DeviceCommand {
    /// Upload a model blob: verified in the device's RAM, stored in flash, put in service.
    Upload {
        /// Management port: a serial device (e.g. /dev/ttyACM1) or tcp:HOST:PORT (QEMU board).
        #[arg(long)]
        port: String,
        /// The blob file (nanocal fit output).
        blob: PathBuf,
    },
    /// Show the device's identity and status: firmware, chip UID, last reset cause, model,
    /// temperatures, faults, extrapolation, KMZ, counters.
    Status {
        /// Management port.
        #[arg(long)]
        port: String,
    },
    /// Set λ_KMZ from a measured reference: the command that was sent and the position measured.
    Kmz {
        /// Management port.
        #[arg(long)]
        port: String,
        /// Commands sent to the controller, µm, one per axis (comma separated).
        #[arg(long, value_delimiter = ',', required = true)]
        q_cmd_um: Vec<f64>,
        /// Positions the reference measured, µm, one per axis (comma separated).
        #[arg(long, value_delimiter = ',', required = true)]
        x_meas_um: Vec<f64>,
    },
    /// Bypass compensation (`on`) or enable it again (`off`).
    Bypass {
        /// Management port.
        #[arg(long)]
        port: String,
        /// on or off.
        #[arg(value_parser = ["on", "off"])]
        state: String,
    },
    /// Show the device's settings, or change them (stored in flash, applied at once; the stage
    /// baud rate at the next reset).
    Config {
        /// Management port.
        #[arg(long)]
        port: String,
        /// Stage link baud rate (8N1).
        #[arg(long)]
        stage_baud: Option<u32>,
        /// Mains frequency: 50 or 60.
        #[arg(long)]
        mains: Option<u32>,
        /// Sensor sampling period, ms (50..=60000).
        #[arg(long)]
        sample_period_ms: Option<u16>,
        /// Fold period, ms (1000..=10000): the readings of a period are averaged and the model
        /// folded with the averages once a period (paper 001 §VI: "each 5-10 seconds").
        #[arg(long)]
        fold_period_ms: Option<u16>,
        /// The model-stale check's k: a KMZ re-measurement whose λ change leaves k standard
        /// errors of prediction raises MODEL_STALE (0 < k ≤ 100; default 3).
        #[arg(long)]
        stale_k: Option<f32>,
        /// How far a temperature may leave the model's training envelope before the model
        /// counts as stale, °C: what the model was shown to extrapolate (0..=50; default 0.1).
        #[arg(long)]
        extrapolation_c: Option<f32>,
        /// Compensate a stage whose controller's serial (`*IDN?`) differs from the one the
        /// model was fitted on (on), or refuse its moves with GCS error 9015 (off, the
        /// default). The status reports the mismatch either way.
        #[arg(long, value_parser = ["on", "off"])]
        allow_other_stage: Option<String>,
        /// Held targets follow the model: while the stage holds the host's target, re-issue its
        /// corrected command when the fold moves it by more than this many nm (0 = off, the
        /// default; at most 10000). The host still reads its own target (MOV?, POS?).
        #[arg(long)]
        follow_nm: Option<u16>,
        /// At most one re-issue per this many ms, the first no sooner after the host's move
        /// (100..=60000; default 10000).
        #[arg(long)]
        follow_interval_ms: Option<u16>,
        /// Largest change of a command per re-issue, nm (0 = no limit, the default).
        #[arg(long)]
        follow_step_nm: Option<u16>,
        /// GCS axis names of model axes 0,1,2 (comma separated), e.g. X,Y,Z.
        #[arg(long, value_delimiter = ',')]
        axes: Option<Vec<String>>,
        /// Amplifier on a chip-select: CS=none, CS=tc:TYPE (MAX31856, TYPE one of B E J K N R S
        /// T), CS=pt100:WIRES or CS=pt1000:WIRES (MAX31865, 2/3/4 wires, R_ref 430/4300 Ω),
        /// or CS=rtd:R0:RREF:WIRES. Repeatable.
        #[arg(long)]
        sensor: Vec<String>,
        /// Source of an aux model input: I=none, I=pressure (LPS22HB, hPa) or
        /// I=force:CHANNEL:N_PER_COUNT:OFFSET_N. Repeatable.
        #[arg(long)]
        aux: Vec<String>,
    },
    /// Reset the device.
    Reset {
        /// Management port.
        #[arg(long)]
        port: String,
    },
}

fn axes(v: &[f64], what: &str) -> anyhow::Result<[f64; 3]> {
    anyhow::ensure!(
        (1..=3).contains(&v.len()),
        "{what}: expected 1 to 3 values (one per axis), found {}",
        v.len()
    );
    let mut a = [0.0; 3];
    a[..v.len()].copy_from_slice(v);
    Ok(a)
}

/// Parse a `--sensor CS=SPEC` argument.
pub fn parse_sensor(arg: &str) -> anyhow::Result<(usize, Option<Chip>)> {
    let (cs, spec) = arg
        .split_once('=')
        .with_context(|| format!("--sensor {arg}: expected CS=SPEC"))?;
    let cs: usize = cs
        .parse()
        .with_context(|| format!("--sensor {arg}: chip-select"))?;
    anyhow::ensure!(
        cs < nanocal_interface::settings::SENSORS,
        "--sensor {arg}: chip-select 0..=7"
    );
    let p: Vec<&str> = spec.split(':').collect();
    let wires = |w: &str| -> anyhow::Result<Wires> {
        Ok(match w {
            "2" => Wires::Two,
            "3" => Wires::Three,
            "4" => Wires::Four,
            _ => bail!("--sensor {arg}: wires must be 2, 3 or 4"),
        })
    };
    let chip = match p.as_slice() {
        ["none"] => None,
        ["tc", t] => {
            let code = "BEJKNRST"
                .find(&t.to_ascii_uppercase())
                .filter(|_| t.len() == 1)
                .with_context(|| format!("--sensor {arg}: thermocouple type B E J K N R S or T"))?;
            Some(Chip::Max31856 { tc: TcType::from_code(code as u8).unwrap() })
        }
        ["pt100", w] => Some(Chip::Max31865 { r_ref_ohm: 430.0, r0_ohm: 100.0, wires: wires(w)? }),
        ["pt1000", w] => Some(Chip::Max31865 { r_ref_ohm: 4300.0, r0_ohm: 1000.0, wires: wires(w)? }),
        ["rtd", r0, rref, w] => Some(Chip::Max31865 {
            r0_ohm: r0.parse().with_context(|| format!("--sensor {arg}: R0"))?,
            r_ref_ohm: rref.parse().with_context(|| format!("--sensor {arg}: R_ref"))?,
            wires: wires(w)?,
        }),
        _ => bail!("--sensor {arg}: expected none, tc:TYPE, pt100:WIRES, pt1000:WIRES or rtd:R0:RREF:WIRES"),
    };
    Ok((cs, chip))
}

/// Parse an `--aux I=SPEC` argument.
pub fn parse_aux(arg: &str) -> anyhow::Result<(usize, AuxSource)> {
    let (i, spec) = arg
        .split_once('=')
        .with_context(|| format!("--aux {arg}: expected I=SPEC"))?;
    let i: usize = i.parse().with_context(|| format!("--aux {arg}: index"))?;
    anyhow::ensure!(
        i < nanocal_model::MAX_AUX,
        "--aux {arg}: index 0..{}",
        nanocal_model::MAX_AUX
    );
    let p: Vec<&str> = spec.split(':').collect();
    let src = match p.as_slice() {
        ["none"] => AuxSource::None,
        ["pressure"] => AuxSource::AirPressure,
        ["force", ch, scale, off] => AuxSource::Force {
            channel: ch
                .parse()
                .with_context(|| format!("--aux {arg}: channel"))?,
            scale_n_per_count: scale
                .parse()
                .with_context(|| format!("--aux {arg}: N per count"))?,
            offset_n: off
                .parse()
                .with_context(|| format!("--aux {arg}: offset"))?,
        },
        _ => bail!("--aux {arg}: expected none, pressure or force:CHANNEL:N_PER_COUNT:OFFSET_N"),
    };
    Ok((i, src))
}

/// Apply the `config` options to `s`; true when anything changed.
#[allow(clippy::too_many_arguments)]
pub fn edit_settings(
    s: &mut Settings,
    stage_baud: Option<u32>,
    mains: Option<u32>,
    sample_period_ms: Option<u16>,
    fold_period_ms: Option<u16>,
    stale: (Option<f32>, Option<f32>),
    allow_other_stage: Option<&str>,
    follow: (Option<u16>, Option<u16>, Option<u16>),
    axes: Option<&[String]>,
    sensors: &[String],
    aux: &[String],
) -> anyhow::Result<bool> {
    let before = *s;
    if let Some(b) = stage_baud {
        s.stage_baud = b;
    }
    if let Some(m) = mains {
        s.mains = match m {
            50 => Mains::Hz50,
            60 => Mains::Hz60,
            _ => bail!("--mains {m}: 50 or 60"),
        };
    }
    if let Some(p) = sample_period_ms {
        s.sample_period_ms = p;
    }
    if let Some(p) = fold_period_ms {
        use nanocal_compensator::slow_average::{MAX_FOLD_PERIOD_MS, MIN_FOLD_PERIOD_MS};
        anyhow::ensure!(
            (MIN_FOLD_PERIOD_MS..=MAX_FOLD_PERIOD_MS).contains(&p),
            "--fold-period-ms {p}: {MIN_FOLD_PERIOD_MS}..={MAX_FOLD_PERIOD_MS}"
        );
        s.fold_period_ms = p;
    }
    let (stale_k, extrapolation_c) = stale;
    if let Some(k) = stale_k {
        use nanocal_interface::settings::MAX_STALE_K;
        anyhow::ensure!(
            k > 0.0 && k <= MAX_STALE_K,
            "--stale-k {k}: greater than 0, at most {MAX_STALE_K}"
        );
        s.stale_k = k;
    }
    if let Some(m) = extrapolation_c {
        use nanocal_interface::settings::MAX_EXTRAPOLATION_C;
        anyhow::ensure!(
            (0.0..=MAX_EXTRAPOLATION_C).contains(&m),
            "--extrapolation-c {m}: 0..={MAX_EXTRAPOLATION_C} °C"
        );
        s.extrapolation_c = m;
    }
    if let Some(a) = allow_other_stage {
        s.allow_other_stage = match a {
            "on" => true,
            "off" => false,
            _ => bail!("--allow-other-stage {a}: on or off"),
        };
    }
    let (follow_nm, follow_interval_ms, follow_step_nm) = follow;
    if let Some(nm) = follow_nm {
        use nanocal_interface::settings::MAX_FOLLOW_NM;
        anyhow::ensure!(
            nm <= MAX_FOLLOW_NM,
            "--follow-nm {nm}: 0 (off) to {MAX_FOLLOW_NM}"
        );
        s.follow_nm = nm;
    }
    if let Some(ms) = follow_interval_ms {
        use nanocal_interface::settings::{MAX_FOLLOW_INTERVAL_MS, MIN_FOLLOW_INTERVAL_MS};
        anyhow::ensure!(
            (MIN_FOLLOW_INTERVAL_MS..=MAX_FOLLOW_INTERVAL_MS).contains(&ms),
            "--follow-interval-ms {ms}: {MIN_FOLLOW_INTERVAL_MS}..={MAX_FOLLOW_INTERVAL_MS}"
        );
        s.follow_interval_ms = ms;
    }
    if let Some(nm) = follow_step_nm {
        s.follow_step_nm = nm;
    }
    if let Some(a) = axes {
        anyhow::ensure!((1..=3).contains(&a.len()), "--axes: 1 to 3 names");
        for (i, n) in a.iter().enumerate() {
            s.axis_names[i] = AxisId::new(n.as_bytes()).with_context(|| {
                format!("--axes: {n:?} is not a GCS axis name (1..8 characters)")
            })?;
        }
    }
    for a in sensors {
        let (cs, chip) = parse_sensor(a)?;
        s.sensors[cs] = chip;
    }
    for a in aux {
        let (i, src) = parse_aux(a)?;
        s.aux[i] = src;
    }
    s.validate()
        .map_err(|e| anyhow::anyhow!("settings rejected: {e}"))?;
    Ok(*s != before)
}

/// Run a device subcommand.
pub fn run(cmd: DeviceCommand) -> anyhow::Result<()> {
    match cmd {
        DeviceCommand::Upload { port, blob } => {
            let bytes =
                std::fs::read(&blob).with_context(|| format!("reading {}", blob.display()))?;
            let mut c = Client::open(&port)?;
            let r = c.upload(&bytes)?;
            println!(
                "model {:#010x} (blob CRC {:#010x}) stored and in service",
                r.model_id, r.model_crc32
            );
        }
        DeviceCommand::Status { port } => {
            let mut c = Client::open(&port)?;
            let h = c.identify()?;
            let site = if h.reset_site.is_empty() {
                String::new()
            } else {
                format!(" at {}", h.reset_site)
            };
            println!(
                "firmware {} (protocol {}, blob format {})  chip UID {}  last reset: {}{site}",
                h.firmware,
                h.protocol,
                h.blob_format,
                uid_hex(&h.uid),
                h.reset_cause
            );
            let s = c.status()?;
            print!("{}", format_status(&s));
        }
        DeviceCommand::Kmz {
            port,
            q_cmd_um,
            x_meas_um,
        } => {
            let q = axes(&q_cmd_um, "--q-cmd-um")?;
            let x = axes(&x_meas_um, "--x-meas-um")?;
            let k = Client::open(&port)?.set_kmz(q, x)?;
            println!("λ_KMZ µm: {:.6} {:.6} {:.6}", k[0], k[1], k[2]);
        }
        DeviceCommand::Bypass { port, state } => {
            let on = state == "on";
            Client::open(&port)?.bypass(on)?;
            println!("compensation {}", if on { "bypassed" } else { "enabled" });
        }
        DeviceCommand::Config {
            port,
            stage_baud,
            mains,
            sample_period_ms,
            fold_period_ms,
            stale_k,
            extrapolation_c,
            allow_other_stage,
            follow_nm,
            follow_interval_ms,
            follow_step_nm,
            axes,
            sensor,
            aux,
        } => {
            let mut c = Client::open(&port)?;
            let mut s = c.config()?;
            let changed = edit_settings(
                &mut s,
                stage_baud,
                mains,
                sample_period_ms,
                fold_period_ms,
                (stale_k, extrapolation_c),
                allow_other_stage.as_deref(),
                (follow_nm, follow_interval_ms, follow_step_nm),
                axes.as_deref(),
                &sensor,
                &aux,
            )?;
            if changed {
                c.set_config(&s)?;
                println!("settings stored:");
            }
            print!("{}", format_settings(&c.config()?));
        }
        DeviceCommand::Reset { port } => {
            Client::open(&port)?.reset()?;
            println!("device reset");
        }
    }
    Ok(())
}
