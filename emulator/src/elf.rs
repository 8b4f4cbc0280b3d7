//! The little of ELF32 the board needs: the loadable segments (what a probe writes to flash and
//! what the start-up code copies to RAM comes from their load addresses) and the symbols (to
//! name a program counter in a fault report, and to find the vector table).

/// A loadable segment: `data` goes to `paddr` (flash for code and initialised data).
pub struct Segment {
    /// Load (physical) address.
    pub paddr: u32,
    /// The file's bytes of the segment.
    pub data: Vec<u8>,
}

/// A symbol: name, value, size.
pub struct Symbol {
    /// Name.
    pub name: String,
    /// Value (address; bit 0 set for Thumb functions).
    pub value: u32,
    /// Size in bytes.
    pub size: u32,
}

/// The parts of an ELF image the board uses.
pub struct Image {
    /// PT_LOAD segments.
    pub segments: Vec<Segment>,
    /// Function and object symbols.
    pub symbols: Vec<Symbol>,
    /// Executable sections: (address, bytes), to find the sleep instructions.
    pub code: Vec<(u32, Vec<u8>)>,
}

/// Why an image cannot be loaded.
#[derive(Debug)]
#[non_exhaustive]
pub enum ElfError {
    /// Not a little-endian 32-bit ELF file.
    NotElf32,
    /// A header points outside the file.
    Truncated(&'static str),
}

impl std::fmt::Display for ElfError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ElfError::NotElf32 => f.write_str("not a little-endian ELF32 file"),
            ElfError::Truncated(what) => write!(f, "ELF {what} outside the file"),
        }
    }
}

impl std::error::Error for ElfError {}

impl Image {
    /// Parse `b`.
    pub fn parse(b: &[u8]) -> Result<Image, ElfError> {
        if b.len() < 0x34 || &b[..6] != b"\x7fELF\x01\x01" {
            return Err(ElfError::NotElf32);
        }
        let get = |o: usize, n: usize, what| b.get(o..o + n).ok_or(ElfError::Truncated(what));
        let u16_at = |o: usize| -> Result<usize, ElfError> {
            let s = get(o, 2, "header")?;
            Ok(u16::from_le_bytes([s[0], s[1]]) as usize)
        };
        let u32_at = |o: usize| -> Result<u32, ElfError> {
            let s = get(o, 4, "header")?;
            Ok(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
        };
        let (phoff, shoff) = (u32_at(0x1C)? as usize, u32_at(0x20)? as usize);
        let (phentsize, phnum) = (u16_at(0x2A)?, u16_at(0x2C)?);
        let (shentsize, shnum) = (u16_at(0x2E)?, u16_at(0x30)?);
        let mut segments = vec![];
        for i in 0..phnum {
            let h = phoff + i * phentsize;
            if u32_at(h)? != 1 {
                continue; // PT_LOAD only
            }
            let (off, paddr, filesz) = (u32_at(h + 4)?, u32_at(h + 0x0C)?, u32_at(h + 0x10)?);
            if filesz == 0 {
                continue;
            }
            let data = get(off as usize, filesz as usize, "segment")?.to_vec();
            segments.push(Segment { paddr, data });
        }
        let mut symbols = vec![];
        let mut code = vec![];
        for i in 0..shnum {
            let h = shoff + i * shentsize;
            let (ty, flags, addr, off, size) = (
                u32_at(h + 4)?,
                u32_at(h + 8)?,
                u32_at(h + 0x0C)?,
                u32_at(h + 0x10)? as usize,
                u32_at(h + 0x14)? as usize,
            );
            if ty == 1 && flags & 0x4 != 0 {
                // SHT_PROGBITS, SHF_EXECINSTR
                code.push((addr, get(off, size, "section")?.to_vec()));
            }
            if ty != 2 {
                continue; // SHT_SYMTAB
            }
            let link = u32_at(h + 0x18)? as usize;
            let stroff = u32_at(shoff + link * shentsize + 0x10)? as usize;
            for k in 0..size / 16 {
                let e = off + k * 16;
                let name_off = stroff + u32_at(e)? as usize;
                let end = b[name_off..].iter().position(|&c| c == 0).unwrap_or(0);
                let name = String::from_utf8_lossy(&b[name_off..name_off + end]).into_owned();
                let info = get(e + 12, 1, "symbol")?[0];
                if matches!(info & 0xF, 1 | 2) && !name.is_empty() {
                    symbols.push(Symbol {
                        name,
                        value: u32_at(e + 4)?,
                        size: u32_at(e + 8)?,
                    });
                }
            }
        }
        Ok(Image {
            segments,
            symbols,
            code,
        })
    }

    /// The function containing `pc`, with the offset into it (`"?"` when none).
    pub fn name_of(&self, pc: u32) -> String {
        self.symbols
            .iter()
            .filter(|s| {
                s.size > 0
                    && s.value >= 0x0800_0000
                    && (s.value & !1) <= pc
                    && pc < (s.value & !1) + s.size
            })
            .map(|s| format!("{}+{:#x}", s.name, pc - (s.value & !1)))
            .next()
            .unwrap_or_else(|| "?".into())
    }

    /// A symbol's value.
    pub fn symbol(&self, name: &str) -> Option<u32> {
        self.symbols
            .iter()
            .find(|s| s.name == name)
            .map(|s| s.value)
    }

    /// Addresses of every 16-bit `hint` instruction (`0xBF00 | op << 4`: WFE 2, WFI 3, SEV 4)
    /// at a halfword boundary of the code (a data halfword that looks like one is never
    /// executed, so a hook on it never fires).
    pub fn hints(&self, op: u16) -> Vec<u32> {
        let want = 0xBF00 | (op << 4);
        let mut out = vec![];
        for (addr, bytes) in &self.code {
            for (i, h) in bytes.chunks_exact(2).enumerate() {
                if u16::from_le_bytes([h[0], h[1]]) == want {
                    out.push(addr + 2 * i as u32);
                }
            }
        }
        out
    }
}
