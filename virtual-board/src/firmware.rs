//! A firmware image: the ELF the bench runs, its symbols and its defmt table.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use object::{Object, ObjectSection, ObjectSymbol, SectionFlags};
use rigless::image::Image;

use crate::soc::Part;

/// One firmware ELF, loaded.
#[derive(Debug)]
pub struct Firmware {
    /// Where it was read from.
    pub path: PathBuf,
    /// The file's bytes.
    pub bytes: Vec<u8>,
    /// The image rigless places.
    pub image: Image,
    symbols: BTreeMap<String, u64>,
    allocated: Vec<(String, u64, u64)>,
}

/// The directory the bench takes the `real` firmwares from: `VBOARD_FIRMWARE_DIR` if set, else
/// the main workspace's `target/firmware/real` (where `cargo xtask fw` puts them).
#[must_use]
pub fn firmware_dir() -> PathBuf {
    dir_from_env("VBOARD_FIRMWARE_DIR", "../target/firmware/real")
}

/// The directory the bench takes the `hil`-flavour firmwares from: `VBOARD_HIL_FIRMWARE_DIR` if
/// set, else the main workspace's `target/firmware/hil` (where `cargo xtask fw --flavour hil`
/// puts them).
#[must_use]
pub fn hil_firmware_dir() -> PathBuf {
    dir_from_env("VBOARD_HIL_FIRMWARE_DIR", "../target/firmware/hil")
}

fn dir_from_env(variable: &str, beside_the_bench: &str) -> PathBuf {
    std::env::var_os(variable).map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join(beside_the_bench),
        PathBuf::from,
    )
}

impl Firmware {
    /// The `real`-flavour image of package `name` (`autopilot` or `stereo-board`), as built by
    /// `cargo xtask fw` (`cargo xtask vboard` builds it first).
    ///
    /// # Errors
    /// The ELF is missing or unreadable.
    pub fn real(name: &str) -> Result<Self, String> {
        Self::built(&firmware_dir(), name, "cargo xtask fw")
    }

    /// The `hil`-flavour image of package `name` (frames, IMU samples and world time from a
    /// host on the board's host UART), as built by `cargo xtask fw --flavour hil` (`cargo xtask
    /// vboard` builds it first).
    ///
    /// # Errors
    /// The ELF is missing or unreadable.
    pub fn hil(name: &str) -> Result<Self, String> {
        Self::built(&hil_firmware_dir(), name, "cargo xtask fw --flavour hil")
    }

    fn built(dir: &Path, name: &str, build: &str) -> Result<Self, String> {
        Self::load(&dir.join(name)).map_err(|e| {
            format!("{e} (build the firmwares first: `{build}`, or run `cargo xtask vboard`)")
        })
    }

    /// Reads an ELF.
    ///
    /// # Errors
    /// The file is missing or not an ELF rigless can place.
    pub fn load(path: &Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let image = Image::new(path, bytes.clone(), None)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let file = object::File::parse(&*bytes).map_err(|e| format!("{}: {e}", path.display()))?;
        let mut symbols = BTreeMap::new();
        for symbol in file.symbols() {
            if let Ok(name) = symbol.name()
                && !name.is_empty()
            {
                symbols.insert(name.to_owned(), symbol.address() & !1);
            }
        }
        let mut allocated = Vec::new();
        for section in file.sections() {
            let alloc = match section.flags() {
                SectionFlags::Elf { sh_flags } => sh_flags & u64::from(object::elf::SHF_ALLOC) != 0,
                _ => false,
            };
            if alloc && section.size() > 0 {
                let name = section.name().unwrap_or("?").to_owned();
                allocated.push((name, section.address(), section.size()));
            }
        }
        Ok(Self {
            path: path.to_owned(),
            bytes,
            image,
            symbols,
            allocated,
        })
    }

    /// The address of the symbol named exactly `name` (a function's without its Thumb bit).
    #[must_use]
    pub fn symbol(&self, name: &str) -> Option<u64> {
        self.symbols.get(name).copied()
    }

    /// Every symbol whose (mangled) name contains `fragment`, for Rust's v0-mangled names.
    pub fn symbols_containing<'a>(
        &'a self,
        fragment: &'a str,
    ) -> impl Iterator<Item = (&'a str, u64)> + 'a {
        self.symbols
            .iter()
            .filter(move |(name, _)| name.contains(fragment))
            .map(|(name, &address)| (name.as_str(), address))
    }

    /// The `len` bytes the image places at `address` (its code and constants), if one segment
    /// holds them all.
    #[must_use]
    pub fn bytes_at(&self, address: u64, len: usize) -> Option<&[u8]> {
        self.image.segments().find_map(|(base, bytes)| {
            let offset = usize::try_from(address.checked_sub(base)?).ok()?;
            bytes.get(offset..offset.checked_add(len)?)
        })
    }

    /// Checks that every section the image occupies at run time and every byte it places lies
    /// in the memory `part` really has (the F427 model has more).
    ///
    /// # Errors
    /// Each section or segment outside, named.
    pub fn check_memory(&self, part: Part) -> Result<(), String> {
        let memory = part.memory();
        let inside = |address: u64, len: u64| memory.iter().any(|r| r.holds(address, len));
        let mut outside = Vec::new();
        for (name, address, size) in &self.allocated {
            if !inside(*address, *size) {
                outside.push(format!("section {name} at {address:#x}+{size:#x}"));
            }
        }
        for (address, bytes) in self.image.segments() {
            if !inside(address, bytes.len() as u64) {
                outside.push(format!("segment at {address:#x}+{:#x}", bytes.len()));
            }
        }
        if outside.is_empty() {
            Ok(())
        } else {
            Err(format!(
                "{} uses memory the {} does not have: {}",
                self.path.display(),
                part.name(),
                outside.join(", ")
            ))
        }
    }

    /// The firmware's defmt table, parsed once and kept for the process (a decoder borrows it).
    ///
    /// # Errors
    /// The ELF carries a defmt section the decoder cannot read.
    pub fn defmt_table(&self) -> Result<Option<&'static defmt_decoder::Table>, String> {
        let table = defmt_decoder::Table::parse(&self.bytes)
            .map_err(|e| format!("{}: defmt table: {e}", self.path.display()))?;
        Ok(table.map(|t| &*Box::leak(Box::new(t))))
    }
}
