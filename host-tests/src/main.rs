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
    /// Run the digital twin and write a simulated recording (CSV).
    Simulate(nanocal::cli::simulate::SimulateArgs),
    /// Find, name and model the physics a model or simulation left out of a recording.
    Explain(nanocal::cli::explain::ExplainArgs),
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().command {
        Command::Limits => {
            println!("nanocal-model {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Command::Simulate(a) => nanocal::cli::simulate::run(a),
        Command::Explain(a) => nanocal::cli::explain::run(a),
    }
}
