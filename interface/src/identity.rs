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
