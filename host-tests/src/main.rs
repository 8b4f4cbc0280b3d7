use clap::{Parser, Subcommand};

/// nanocal: calibrate nanopositioning stages and ultra-precision robots for open-loop accuracy.
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the build's limits of the shared model (axes, temperatures, terms).
    Limits,
    /// Stepwise regression (MATLAB stepwisefit semantics) on the columns of a CSV file.
    Stepwise(nanocal::cli::stepwise::StepwiseArgs),
    /// Run the digital twin and write a simulated recording (CSV).
    Simulate(nanocal::cli::simulate::SimulateArgs),
    /// The inline compensator: upload a model, status, KMZ, bypass.
    #[command(subcommand)]
    Device(nanocal::cli::device::DeviceCommand),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Limits => {
            println!("nanocal-model {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Command::Stepwise(a) => nanocal::cli::stepwise::run(a),
        Command::Simulate(a) => nanocal::cli::simulate::run(a),
        Command::Device(cmd) => nanocal::cli::device::run(cmd),
    }
}
