//! `nanocal device upload|status|kmz|bypass`: the inline compensator's management channel.

use crate::device::{format_status, Client};
use anyhow::Context;
use clap::Subcommand;
use std::path::PathBuf;

/// Device subcommands.
#[derive(Subcommand, Debug)]
pub enum DeviceCommand {
    /// Upload a model blob: verified in the device's RAM, committed to flash, put in service.
    Upload {
        /// Management port: a serial device (e.g. /dev/ttyACM1) or tcp:HOST:PORT (QEMU board).
        #[arg(long)]
        port: String,
        /// The blob file (nanocal fit output).
        blob: PathBuf,
    },
    /// Show the device's status: model, temperatures, faults, extrapolation, KMZ, counters.
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

/// Run a device subcommand.
pub fn run(cmd: DeviceCommand) -> anyhow::Result<()> {
    match cmd {
        DeviceCommand::Upload { port, blob } => {
            let bytes =
                std::fs::read(&blob).with_context(|| format!("reading {}", blob.display()))?;
            let mut c = Client::open(&port)?;
            let r = c.upload(&bytes)?;
            println!(
                "model {:#010x} in service (slot {}, seq {})",
                r.model_id, r.slot, r.seq
            );
        }
        DeviceCommand::Status { port } => {
            let s = Client::open(&port)?.status()?;
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
    }
    Ok(())
}
