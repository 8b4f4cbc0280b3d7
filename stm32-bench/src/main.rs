//! `stm32-bench campaign …`: `nanocal campaign --virtual --board stm32 …` on the emulated
//! B-L475E-IOT01A. The nanocal CLI runs this binary with its own arguments (from `campaign`
//! on); it is a separate GPL-2.0 program because the emulated board links Unicorn (GPL-2.0),
//! which the MIT/Apache nanocal library and CLI must not link.

use clap::{Parser, Subcommand};
use nanocal::campaign::state::VirtualBoard;
use nanocal::cli::campaign::CampaignArgs;

#[derive(Parser)]
#[command(
    version,
    about = "nanocal campaigns on the emulated B-L475E-IOT01A (run by `nanocal campaign --virtual --board stm32`)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// `nanocal campaign` with `--virtual --board stm32` (or `--resume` of such a campaign).
    Campaign(CampaignArgs),
}

fn main() -> anyhow::Result<()> {
    let Command::Campaign(args) = Cli::parse().command;
    let board = nanocal::cli::campaign::board_of(&args)?;
    anyhow::ensure!(
        board == Some(VirtualBoard::Stm32),
        "stm32-bench runs campaigns on the emulated STM32 board only: give --virtual --board stm32 (or --resume such a campaign); `nanocal campaign` runs the others"
    );
    nanocal::cli::campaign::run_on(args, Some(&mut nanocal_stm32_bench::bench::open))
}
