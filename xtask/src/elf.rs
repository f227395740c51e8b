//! Flash and RAM use of the firmware, from the ELF's section headers (32-bit
//! little-endian ELF, as the linker writes for thumbv7em).

use std::path::Path;

/// Where the firmware's RAM begins (`memory.x`); sections below are in flash.
const RAM_ORIGIN: u32 = 0x2000_0000;
/// Section header flag: occupies memory at run time.
const SHF_ALLOC: u32 = 0x2;
/// Section type: no bytes in the file (`.bss`, `.uninit`).
const SHT_NOBITS: u32 = 8;

/// One allocated section.
#[derive(Debug)]
pub struct Section {
    /// Name.
    pub name: String,
    /// Run-time address.
    pub addr: u32,
    /// Size, bytes.
    pub size: u32,
    /// Whether its bytes are stored in the image (false for `.bss`).
    pub has_bytes: bool,
}

/// Memory use of an image.
#[derive(Debug)]
pub struct Usage {
    /// Bytes in flash: code, read-only data, vector table and the initial values of `.data`.
    pub flash_bytes: u32,
    /// Bytes of RAM taken by statics (`.data`, `.bss`, `.uninit`).
    pub static_ram_bytes: u32,
    /// The sections counted.
    pub sections: Vec<Section>,
}

fn u16_at(d: &[u8], at: usize) -> Result<u16, String> {
    d.get(at..at + 2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .ok_or_else(|| format!("ELF truncated at {at}"))
}

fn u32_at(d: &[u8], at: usize) -> Result<u32, String> {
    d.get(at..at + 4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .ok_or_else(|| format!("ELF truncated at {at}"))
}

/// Reads the section table of `path`.
pub fn usage(path: &Path) -> Result<Usage, String> {
    let d = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let err = |what: &str| format!("{}: {what}", path.display());
    if d.get(..4) != Some(b"\x7fELF") || d.get(4) != Some(&1) || d.get(5) != Some(&1) {
        return Err(err("not a 32-bit little-endian ELF file"));
    }
    let shoff = u32_at(&d, 0x20)? as usize;
    let shentsize = u16_at(&d, 0x2E)? as usize;
    let shnum = u16_at(&d, 0x30)? as usize;
    let shstrndx = u16_at(&d, 0x32)? as usize;
    let header = |i: usize| shoff + i * shentsize;
    let strtab = u32_at(&d, header(shstrndx) + 0x10)? as usize;
    let mut sections = Vec::new();
    for i in 0..shnum {
        let h = header(i);
        let (name_off, kind, flags) = (u32_at(&d, h)? as usize, u32_at(&d, h + 4)?, u32_at(&d, h + 8)?);
        let (addr, size) = (u32_at(&d, h + 0x0C)?, u32_at(&d, h + 0x14)?);
        if flags & SHF_ALLOC == 0 || size == 0 {
            continue;
        }
        let start = strtab + name_off;
        let end = d
            .get(start..)
            .and_then(|s| s.iter().position(|&b| b == 0))
            .ok_or_else(|| err("bad section name"))?;
        let name = String::from_utf8_lossy(&d[start..start + end]).into_owned();
        sections.push(Section { name, addr, size, has_bytes: kind != SHT_NOBITS });
    }
    let flash_bytes = sections.iter().filter(|s| s.addr < RAM_ORIGIN || s.has_bytes).map(|s| s.size).sum();
    let static_ram_bytes = sections.iter().filter(|s| s.addr >= RAM_ORIGIN).map(|s| s.size).sum();
    Ok(Usage { flash_bytes, static_ram_bytes, sections })
}
