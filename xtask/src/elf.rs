//! The firmware ELF files as xtask reads them (section headers and symbol values), parsed with
//! the `object` crate, the same reader the virtual-board bench loads images with.

use anyhow::{bail, Context, Result};
use object::read::elf::{ElfFile32, SectionHeader as _};
use object::{elf, Endianness, Object, ObjectSection, ObjectSymbol, SectionFlags};

/// One section of an image (the fields the size report uses).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Section {
    /// Section name.
    pub name: String,
    /// Load address.
    pub addr: u64,
    /// Bytes the section occupies in memory.
    pub size: u64,
    /// Occupies memory at run time (`SHF_ALLOC`).
    pub alloc: bool,
    /// Has no bytes in the file (`SHT_NOBITS`: zeroed or uninitialised at start-up).
    pub nobits: bool,
}

/// Parses a 32-bit little-endian ELF, the format every image of ours is linked to.
fn parse(bytes: &[u8]) -> Result<ElfFile32<'_, Endianness>> {
    let file = ElfFile32::<Endianness>::parse(bytes).context("not a 32-bit ELF file")?;
    if file.is_little_endian() {
        Ok(file)
    } else {
        bail!("not a little-endian ELF file")
    }
}

/// Every section of the ELF image in `bytes`.
pub fn sections(bytes: &[u8]) -> Result<Vec<Section>> {
    let file = parse(bytes)?;
    file.sections()
        .map(|s| {
            let name = s.name().context("section name outside the string table")?;
            let (alloc, nobits) = match s.flags() {
                SectionFlags::Elf { sh_flags } => (
                    sh_flags & u64::from(elf::SHF_ALLOC) != 0,
                    s.elf_section_header().sh_type(file.endian()) == elf::SHT_NOBITS,
                ),
                _ => (false, false),
            };
            Ok(Section {
                name: name.to_string(),
                addr: s.address(),
                size: s.size(),
                alloc,
                nobits,
            })
        })
        .collect()
}

/// Value of the named symbol in the image's symbol table (`None` when it is not there). A Thumb
/// function's value keeps its bit 0 set, as the linker wrote it.
pub fn symbol(bytes: &[u8], wanted: &str) -> Result<Option<u32>> {
    let file = parse(bytes)?;
    if file.symbol_table().is_none() {
        bail!("no symbol table");
    }
    for sym in file.symbols() {
        if sym
            .name_bytes()
            .context("symbol name outside the string table")?
            == wanted.as_bytes()
        {
            let value = u32::try_from(sym.address()).context("symbol value beyond 32 bits")?;
            return Ok(Some(value));
        }
    }
    Ok(None)
}
