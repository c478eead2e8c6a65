//! The firmware image: what it occupies in flash and RAM, and its UF2.

use object::elf::{FileHeader32, PT_LOAD, SHF_ALLOC};
use object::read::elf::{FileHeader, ProgramHeader, SectionHeader};
use object::LittleEndian;

/// RP2040 flash window (XIP) and SRAM.
pub const FLASH: std::ops::Range<u32> = 0x1000_0000..0x1100_0000;
/// SRAM (264 KiB).
pub const RAM: std::ops::Range<u32> = 0x2000_0000..0x2004_2000;
/// UF2 family ID of the RP2040.
pub const RP2040_FAMILY: u32 = 0xe48b_ff56;

/// Why an image could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// Not a 32-bit little-endian ELF, or its tables are damaged.
    #[error("not a readable 32-bit little-endian ELF: {0}")]
    Elf(#[from] object::read::Error),
    /// A segment's bytes lie past the end of the file.
    #[error("a segment's bytes lie past the end of the file")]
    Truncated,
    /// A loadable segment lies outside the flash window.
    #[error("segment at 0x{addr:08x} ({len} bytes) is outside the RP2040 flash")]
    OutsideFlash {
        /// Load address.
        addr: u32,
        /// Length.
        len: u32,
    },
}

/// Flash and RAM figures of a firmware ELF.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Usage {
    /// Bytes stored in flash: code, constants, the initial values of `.data`, boot2, vectors.
    pub flash: u64,
    /// Statically allocated RAM: `.data` + `.bss` + `.uninit` (the stack takes what is left).
    pub ram: u64,
}

impl Usage {
    /// Flash size of a Pico (2 MiB).
    pub const FLASH_TOTAL: u64 = 2 * 1024 * 1024;
    /// RAM size (264 KiB).
    pub const RAM_TOTAL: u64 = 264 * 1024;
}

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "flash {} B ({:.1} % of 2 MiB), RAM {} B static ({:.1} % of 264 KiB; the stack has the rest)",
            self.flash,
            100.0 * self.flash as f64 / Self::FLASH_TOTAL as f64,
            self.ram,
            100.0 * self.ram as f64 / Self::RAM_TOTAL as f64
        )
    }
}

type Elf = FileHeader32<LittleEndian>;

/// `(load address, bytes)` of every loadable segment with contents.
pub fn load_segments(elf: &[u8]) -> Result<Vec<(u32, &[u8])>, ImageError> {
    let header = Elf::parse(elf)?;
    let e = header.endian()?;
    let mut out = Vec::new();
    for ph in header.program_headers(e, elf)? {
        if ph.p_type(e) != PT_LOAD || ph.p_filesz(e) == 0 {
            continue;
        }
        // The physical (load) address: `.data`'s initial values live in flash.
        let addr = ph.p_paddr(e);
        let data = ph.data(e, elf).map_err(|()| ImageError::Truncated)?;
        let len = data.len() as u32;
        if !(FLASH.contains(&addr) && addr.checked_add(len).is_some_and(|end| end <= FLASH.end)) {
            return Err(ImageError::OutsideFlash { addr, len });
        }
        out.push((addr, data));
    }
    Ok(out)
}

/// Flash and RAM use of `elf`.
pub fn usage(elf: &[u8]) -> Result<Usage, ImageError> {
    let flash = load_segments(elf)?
        .iter()
        .map(|(_, d)| d.len() as u64)
        .sum();
    let header = Elf::parse(elf)?;
    let e = header.endian()?;
    let mut ram = 0;
    for s in header.section_headers(e, elf)? {
        if s.sh_flags(e).0 & SHF_ALLOC.0 != 0 && RAM.contains(&s.sh_addr(e)) {
            ram += s.sh_size(e) as u64;
        }
    }
    Ok(Usage { flash, ram })
}

/// The UF2 image of `elf` for the RP2040 bootloader: 512-byte blocks, each carrying one
/// 256-byte flash page (pages touched by a segment; gaps inside a page are 0), with the
/// RP2040 family ID.
pub fn uf2(elf: &[u8]) -> Result<Vec<u8>, ImageError> {
    let segments = load_segments(elf)?;
    let mut pages: std::collections::BTreeMap<u32, [u8; 256]> = Default::default();
    for (addr, data) in segments {
        for (i, b) in data.iter().enumerate() {
            let a = addr + i as u32;
            pages.entry(a & !255).or_insert([0; 256])[(a & 255) as usize] = *b;
        }
    }
    let total = pages.len() as u32;
    let mut out = Vec::with_capacity(pages.len() * 512);
    for (n, (addr, page)) in pages.iter().enumerate() {
        let mut block = [0u8; 512];
        let words: [u32; 8] = [
            0x0A32_4655,   // magic 0
            0x9E5D_5157,   // magic 1
            0x0000_2000,   // flags: family ID present
            *addr,         // target address
            256,           // payload size
            n as u32,      // block number
            total,         // number of blocks
            RP2040_FAMILY, // family ID
        ];
        for (i, w) in words.iter().enumerate() {
            block[i * 4..i * 4 + 4].copy_from_slice(&w.to_le_bytes());
        }
        block[32..32 + 256].copy_from_slice(page);
        block[508..512].copy_from_slice(&0x0AB1_6F30u32.to_le_bytes()); // final magic
        out.extend_from_slice(&block);
    }
    Ok(out)
}
