//! Who the device is and why it last started: chip UID, firmware version, reset cause.

use core::fmt;

/// Why the microcontroller last reset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ResetCause {
    /// Power-on or brown-out (BOR).
    PowerOn,
    /// The reset pin (the board's reset button, or the debugger).
    Pin,
    /// Software reset (a management `RESET`, or after a firmware update).
    Software,
    /// The independent watchdog: the firmware hung and was restarted.
    Watchdog,
    /// The window watchdog.
    WindowWatchdog,
    /// Low-power mode entered illegally.
    LowPower,
    /// Option bytes loaded, or firewall.
    Other,
    /// No flag set (unknown).
    Unknown,
    /// The firmware panicked (a bug); the site is in [`Site`].
    Panic,
    /// A double ECC error outside the store: the firmware's own flash (code, constants) is
    /// damaged — reflash the board; the address is in [`Site`].
    FlashEcc,
    /// The CPU faulted (HardFault: an undefined instruction, a bad access); the PC is in
    /// [`Site`].
    Fault,
}

impl ResetCause {
    /// Stable code for the management protocol.
    pub fn code(self) -> u8 {
        match self {
            ResetCause::PowerOn => 1,
            ResetCause::Pin => 2,
            ResetCause::Software => 3,
            ResetCause::Watchdog => 4,
            ResetCause::WindowWatchdog => 5,
            ResetCause::LowPower => 6,
            ResetCause::Other => 7,
            ResetCause::Unknown => 0,
            ResetCause::Panic => 8,
            ResetCause::FlashEcc => 9,
            ResetCause::Fault => 10,
        }
    }

    /// Inverse of [`ResetCause::code`].
    pub fn from_code(c: u8) -> Self {
        match c {
            1 => ResetCause::PowerOn,
            2 => ResetCause::Pin,
            3 => ResetCause::Software,
            4 => ResetCause::Watchdog,
            5 => ResetCause::WindowWatchdog,
            6 => ResetCause::LowPower,
            7 => ResetCause::Other,
            8 => ResetCause::Panic,
            9 => ResetCause::FlashEcc,
            10 => ResetCause::Fault,
            _ => ResetCause::Unknown,
        }
    }

    /// From the STM32L4 RCC_CSR flags (RM0351 §6.4.29: bit 31 LPWRRSTF, 30 WWDGRSTF,
    /// 29 IWDGRSTF, 28 SFTRSTF, 27 BORRSTF, 26 PINRSTF, 25 OBLRSTF, 24 FWRSTF). A power-on sets
    /// BORRSTF and PINRSTF together, so the most specific flag wins.
    pub fn from_rcc_csr(csr: u32) -> Self {
        let bit = |n: u32| csr & (1 << n) != 0;
        if bit(29) {
            ResetCause::Watchdog
        } else if bit(30) {
            ResetCause::WindowWatchdog
        } else if bit(31) {
            ResetCause::LowPower
        } else if bit(28) {
            ResetCause::Software
        } else if bit(25) || bit(24) {
            ResetCause::Other
        } else if bit(27) {
            ResetCause::PowerOn
        } else if bit(26) {
            ResetCause::Pin
        } else {
            ResetCause::Unknown
        }
    }
}

impl fmt::Display for ResetCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            ResetCause::PowerOn => "power-on / brown-out",
            ResetCause::Pin => "reset pin",
            ResetCause::Software => "software reset",
            ResetCause::Watchdog => "independent watchdog (the firmware hung)",
            ResetCause::WindowWatchdog => "window watchdog",
            ResetCause::LowPower => "illegal low-power entry",
            ResetCause::Other => "option-byte load or firewall",
            ResetCause::Unknown => "unknown",
            ResetCause::Panic => "panic (a firmware bug)",
            ResetCause::FlashEcc => "double ECC error in the firmware's flash (reflash the board)",
            ResetCause::Fault => "CPU fault (HardFault)",
        })
    }
}

/// Where a reset the firmware recorded itself came from ([`ResetCause::Panic`],
/// [`ResetCause::FlashEcc`], [`ResetCause::Fault`]): kept over the reset (on the STM32 board in
/// RTC backup registers) and reported in HELLO after the reset cause as text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Site<'a> {
    /// Nothing recorded.
    None,
    /// A source line (a panic).
    Line {
        /// Source file.
        file: &'a str,
        /// Line.
        line: u32,
    },
    /// An address (the double word with the ECC error, or the faulting PC).
    Address(u32),
}

impl Site<'_> {
    /// The site as text into `out` (`file:line`, or `0x` and eight hex digits); its length
    /// (cut to `out`).
    pub fn write(&self, out: &mut [u8]) -> usize {
        let mut n = 0;
        let mut push = |b: u8| {
            if let Some(c) = out.get_mut(n) {
                *c = b;
                n += 1;
            }
        };
        match *self {
            Site::None => {}
            Site::Line { file, line } => {
                file.bytes().for_each(&mut push);
                push(b':');
                let mut digits = [0u8; 10];
                let mut k = 0;
                let mut v = line;
                loop {
                    digits[k] = b'0' + (v % 10) as u8;
                    k += 1;
                    v /= 10;
                    if v == 0 {
                        break;
                    }
                }
                digits[..k].iter().rev().for_each(|&d| push(d));
            }
            Site::Address(a) => {
                const HEX: &[u8; 16] = b"0123456789abcdef";
                push(b'0');
                push(b'x');
                for i in (0..8).rev() {
                    push(HEX[((a >> (4 * i)) & 0xF) as usize]);
                }
            }
        }
        n
    }
}

/// The USB serial number for a chip UID: the 96-bit UID as 24 upper-case hex digits, so two
/// boards never enumerate with the same serial (udev `ATTRS{serial}` tells them apart).
pub fn usb_serial(uid: &[u8; 12], out: &mut [u8; 24]) {
    const HEX: &[u8; 16] = b"0123456789ABCDEF";
    for (i, b) in uid.iter().enumerate() {
        out[2 * i] = HEX[usize::from(b >> 4)];
        out[2 * i + 1] = HEX[usize::from(b & 0x0F)];
    }
}
