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
    /// Fit a calibration model to a training recording and write the model blob.
    Fit(nanocal::cli::fit::FitArgs),
    /// Write a model's correction of one axis as a bidirectional error table (CSV).
    ExportTable(nanocal::cli::export::ExportTableArgs),
    /// Import a PI data-recorder file (GCSArray, `DRR?` reply) as a recording.
    Import(nanocal::cli::import::ImportArgs),
    /// Validate a model on a recording: no model / static / adaptive KMZ, ISO 9283 metrics.
    Validate(nanocal::cli::validate::ValidateArgs),
    /// Validate and write the report plots (PNG + SVG).
    Report(nanocal::cli::report::ReportArgs),
    /// A whole calibration campaign on a bench through the compensator (or `--virtual`).
    Campaign(nanocal::cli::campaign::CampaignArgs),
    /// The whole workflow on the bundled example: train, fit, validate, table, plots.
    Demo(nanocal::cli::demo::DemoArgs),
    /// Run the digital twin and write a simulated recording (CSV).
    Simulate(nanocal::cli::simulate::SimulateArgs),
    /// The inline compensator: upload a model, status, KMZ, bypass.
    #[command(subcommand)]
    Device(nanocal::cli::device::DeviceCommand),
    /// Find, name and model the physics a model or simulation left out of a recording.
    Explain(nanocal::cli::explain::ExplainArgs),
}

fn main() -> anyhow::Result<()> {
    // explain's million-row vectors: freed memory stays in the process for the next one
    nanocal::cli::memory::reuse_freed_memory();
    match Cli::parse().command {
        Command::Limits => {
            use nanocal::model::{blob, limits, FOLD_CAPACITY};
            println!("nanocal-model {}", env!("CARGO_PKG_VERSION"));
            println!("axes                 {}", limits::MAX_AXES);
            println!("temperature inputs   {}", limits::MAX_TEMPS);
            println!(
                "aux inputs           {} (slow or fast; air pressure hPa, force N, other)",
                limits::MAX_AUX
            );
            println!("lag filters          {}", limits::MAX_LAGS);
            println!(
                "play operators       {} (hysteresis, 16 per axis on 3 axes)",
                limits::MAX_PLAY
            );
            println!("terms                {}", limits::MAX_TERMS);
            println!("power per term       {}", limits::MAX_POWER);
            println!("fold coefficients    {FOLD_CAPACITY}");
            println!(
                "blob format version  {} (reads {} and {})",
                blob::FORMAT_VERSION,
                blob::FORMAT_VERSION_1,
                blob::FORMAT_VERSION
            );
            println!("largest blob         {} bytes", blob::MAX_BLOB_LEN);
            Ok(())
        }
        Command::Stepwise(a) => nanocal::cli::stepwise::run(a),
        Command::Fit(a) => nanocal::cli::fit::run(a),
        Command::Import(a) => nanocal::cli::import::run(a),
        Command::ExportTable(a) => nanocal::cli::export::run(a),
        Command::Validate(a) => nanocal::cli::validate::run(a),
        Command::Report(a) => nanocal::cli::report::run(a),
        Command::Campaign(a) => nanocal::cli::campaign::run(a),
        Command::Demo(a) => nanocal::cli::demo::run(a),
        Command::Simulate(a) => nanocal::cli::simulate::run(a),
        Command::Device(cmd) => nanocal::cli::device::run(cmd),
        Command::Explain(a) => nanocal::cli::explain::run(a),
    }
}
