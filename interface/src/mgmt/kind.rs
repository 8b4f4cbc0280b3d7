//! Request kinds (the frame's `kind` byte; a reply's is the request's with [`REPLY`] set).

/// Bit set in reply kinds.
pub const REPLY: u8 = 0x80;

code_enum! {
    /// What a management request asks.
    pub enum Kind: u8 {
        /// Identify: protocol, blob format, chunk size, firmware, chip UID, reset cause.
        Hello = 0x01 => "identify",
        /// Status report.
        Status = 0x02 => "status",
        /// Start an upload.
        UploadBegin = 0x10 => "upload begin",
        /// One chunk of an upload.
        UploadChunk = 0x11 => "upload chunk",
        /// Verify, store and activate the upload.
        UploadCommit = 0x12 => "upload commit",
        /// Drop the upload.
        UploadAbort = 0x13 => "upload abort",
        /// Set λ_KMZ from a measured reference.
        SetKmz = 0x20 => "set λ_KMZ",
        /// Bypass (on) or enable (off) compensation.
        Bypass = 0x21 => "bypass",
        /// Read the settings.
        ConfigGet = 0x30 => "read settings",
        /// Store and apply settings.
        ConfigSet = 0x31 => "store settings",
        /// Reset the device (after the reply).
        Reset = 0x32 => "reset",
        /// QEMU board only: the firmware hangs in a busy loop (the watchdog test's hung
        /// firmware); other boards refuse it as an unknown kind.
        DebugHang = 0x7E => "hang (QEMU watchdog test)",
    }
}

impl Kind {
    /// The kind byte of this request's reply.
    pub const fn reply_code(self) -> u8 {
        self.code() | REPLY
    }
}
