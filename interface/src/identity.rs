//! Who the device is and why it last started: the reset cause (HELLO and STATUS carry its
//! code) and the USB serial number derived from the chip UID (udev tells boards apart by it).

code_enum! {
    /// Why the microcontroller last reset.
    pub enum ResetCause: u8 {
        /// No flag set (unknown).
        Unknown = 0 => "unknown",
        /// Power-on or brown-out (BOR).
        PowerOn = 1 => "power-on / brown-out",
        /// The reset pin (the board's reset button, or the debugger).
        Pin = 2 => "reset pin",
        /// Software reset (a management `RESET`, or after a firmware update).
        Software = 3 => "software reset",
        /// The independent watchdog: the firmware hung and was restarted.
        Watchdog = 4 => "independent watchdog (the firmware hung)",
        /// The window watchdog.
        WindowWatchdog = 5 => "window watchdog",
        /// Low-power mode entered illegally.
        LowPower = 6 => "illegal low-power entry",
        /// Option bytes loaded, or firewall.
        Other = 7 => "option-byte load or firewall",
        /// The firmware panicked (a bug); HELLO's reset site says where ([`Site`]).
        Panic = 8 => "panic (a firmware bug)",
        /// A double ECC error outside the store: the firmware's own flash (code, constants)
        /// is damaged — reflash the board; the reset site has the address.
        FlashEcc = 9 => "double ECC error in the firmware's flash (reflash the board)",
        /// The CPU faulted (HardFault: an undefined instruction, a bad access); the reset site
        /// has the PC.
        Fault = 10 => "CPU fault (HardFault)",
    }
}

impl ResetCause {
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

/// Longest reset site text in `HELLO`.
pub const MAX_SITE: usize = 64;

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

    /// The site as HELLO's text ([`Self::write`], cut to [`MAX_SITE`] bytes; empty for
    /// [`Site::None`], and for a file name that is not ASCII).
    pub fn text(&self) -> heapless::String<MAX_SITE> {
        let mut buf = [0u8; MAX_SITE];
        let n = self.write(&mut buf);
        let mut s = heapless::String::new();
        if buf[..n].is_ascii() {
            // ASCII is UTF-8, and n <= MAX_SITE
            let _ = s.push_str(core::str::from_utf8(&buf[..n]).unwrap_or(""));
        }
        s
    }
}

/// Bytes of the chip's unique ID (the STM32's 96 bits).
pub const UID_LEN: usize = 12;

/// The USB serial number for a chip UID: the 96-bit UID as 24 upper-case hex digits, so two
/// boards never enumerate with the same serial (udev `ATTRS{serial}` tells them apart).
pub fn usb_serial(uid: &[u8; UID_LEN], out: &mut [u8; 2 * UID_LEN]) {
    const HEX: &[u8; 16] = b"0123456789ABCDEF";
    for (i, b) in uid.iter().enumerate() {
        out[2 * i] = HEX[usize::from(b >> 4)];
        out[2 * i + 1] = HEX[usize::from(b & 0x0F)];
    }
}
