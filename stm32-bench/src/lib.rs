//! nanocal on the emulated B-L475E-IOT01A (`nanocal-stm32-board`, GPL-2.0 as it links Unicorn):
//! the rig that runs the shipped STM32 image with the virtual bench's controller and chips
//! around it ([`rig`], the host tests' `tests/stm32_sim/`), and the campaign's virtual bench on
//! it ([`bench`], run by the `stm32-bench` binary that `nanocal campaign --virtual --board
//! stm32` starts as a process, so that the MIT/Apache nanocal CLI never links GPL code).

pub mod bench;
pub mod rig;
