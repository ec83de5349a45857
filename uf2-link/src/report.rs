//! Flash and RAM use of a linked firmware, from its ELF sections.

use object::elf;
use object::read::elf::{ElfFile32, FileHeader, ProgramHeader};
use object::{Object, ObjectSection, ObjectSymbol, SectionFlags, SectionKind};

/// The Cortex-M SRAM region: where every supported chip's RAM lies.
const RAM: core::ops::Range<u64> = 0x2000_0000..0x4000_0000;

/// One allocated section's share.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Part {
    /// Section address (the report lists sections in address order).
    pub addr: u64,
    /// Section name.
    pub name: String,
    /// Bytes.
    pub size: u64,
}

/// What the firmware takes of flash and RAM.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Usage {
    /// Bytes the loadable segments put into flash (what the UF2 carries,
    /// initial values of `.data` included).
    pub flash: u64,
    /// Sections whose bytes are stored in flash.
    pub flash_parts: Vec<Part>,
    /// Bytes of RAM taken by statics (`.data`, `.bss`, `.uninit`).
    pub ram_static: u64,
    /// Sections that live in RAM.
    pub ram_parts: Vec<Part>,
    /// RAM left between the end of the statics and the initial stack
    /// pointer: the most the stack can grow, if the symbols are there.
    pub stack: Option<u64>,
}

/// A loadable segment: its load address and bytes.
pub type Segment = (u32, Vec<u8>);

/// Loadable bytes of an ELF as (flash address, bytes) pairs, by physical
/// (load) address, so `.data`'s initial values land in flash where the
/// startup code copies them from.
pub fn load_segments(data: &[u8]) -> Result<Vec<Segment>, Box<dyn std::error::Error>> {
    let file = ElfFile32::<object::LittleEndian>::parse(data)?;
    let endian = file.endian();
    let mut out = Vec::new();
    for ph in file.elf_header().program_headers(endian, data)? {
        if ph.p_type(endian) != elf::PT_LOAD || ph.p_filesz(endian) == 0 {
            continue;
        }
        let bytes = ph
            .data(endian, data)
            .map_err(|()| "a segment's data lies outside the file")?;
        out.push((ph.p_paddr(endian), bytes.to_vec()));
    }
    Ok(out)
}

/// Sums the allocated sections of an ELF by where they live; `flash` is
/// the chip's program flash window.
pub fn usage(data: &[u8], flash: &crate::uf2::Window) -> Result<Usage, Box<dyn std::error::Error>> {
    let flash = u64::from(flash.start)..u64::from(flash.end);
    let file = ElfFile32::<object::LittleEndian>::parse(data)?;
    let mut u = Usage {
        flash: load_segments(data)?
            .iter()
            .map(|(_, b)| b.len() as u64)
            .sum(),
        ..Usage::default()
    };
    let mut ram_end = RAM.start;
    for s in file.sections() {
        let alloc = matches!(s.flags(), SectionFlags::Elf { sh_flags } if sh_flags & u64::from(elf::SHF_ALLOC) != 0);
        if !alloc || s.size() == 0 {
            continue;
        }
        let part = Part {
            addr: s.address(),
            name: s.name().unwrap_or("?").to_string(),
            size: s.size(),
        };
        let in_ram = RAM.contains(&s.address());
        let has_bytes = s.kind() != SectionKind::UninitializedData;
        if in_ram {
            u.ram_static += s.size();
            ram_end = ram_end.max(s.address() + s.size());
            if has_bytes {
                u.flash_parts.push(part.clone());
            }
            u.ram_parts.push(part);
        } else if flash.contains(&s.address()) && has_bytes {
            u.flash_parts.push(part);
        }
    }
    // Flash-resident sections by address, then `.data`'s initial values.
    u.flash_parts.sort_by_key(|p| p.addr);
    u.flash_parts.sort_by_key(|p| RAM.contains(&p.addr));
    u.ram_parts.sort_by_key(|p| p.addr);
    u.stack = file
        .symbols()
        .find(|s| s.name() == Ok("_stack_start"))
        .map(|s| s.address().saturating_sub(ram_end));
    Ok(u)
}

/// Formats `n` bytes with a thin grouping, e.g. `45 312`.
fn group(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(' ');
        }
        out.push(c);
    }
    out
}

impl Usage {
    /// The report printed after every link.
    pub fn render(&self) -> String {
        let parts = |ps: &[Part]| {
            ps.iter()
                .map(|p| format!("{} {}", p.name, group(p.size)))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let mut s = format!(
            "flash {} B ({}); RAM {} B static ({})",
            group(self.flash),
            parts(&self.flash_parts),
            group(self.ram_static),
            parts(&self.ram_parts),
        );
        if let Some(stack) = self.stack {
            s += &format!(" + up to {} B of stack", group(stack));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::group;

    #[test]
    fn grouping() {
        assert_eq!(group(0), "0");
        assert_eq!(group(999), "999");
        assert_eq!(group(1000), "1 000");
        assert_eq!(group(45312), "45 312");
        assert_eq!(group(1234567), "1 234 567");
    }
}
