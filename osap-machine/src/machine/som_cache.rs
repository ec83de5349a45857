//! Where a machine keeps what it read of its modules' functions between
//! starts: one [`SomCache`] per machine file, in the user's cache folder
//! (`osap/som/` there), or in the folder `OSAP_SOM_CACHE` names; with
//! `OSAP_SOM_CACHE=off`, none. The cache trusts a module only while it
//! reports the same build and function-set id (see [`SomCache`]), so a
//! changed network is read afresh, never taken stale.

use std::path::PathBuf;

use osap_host::som::SomCache;

use crate::config::MachineFile;

/// The cache file of machine file `cfg`, by its name and folder; `None`
/// when caching is off or there is no cache folder.
pub(super) fn path(cfg: &MachineFile) -> Option<PathBuf> {
    let dir = match std::env::var_os("OSAP_SOM_CACHE") {
        Some(v) if v == "off" => return None,
        Some(v) => PathBuf::from(v),
        None => dirs::cache_dir()?.join("osap").join("som"),
    };
    // Two machine files of one name in different folders keep apart.
    let folder = cfg
        .source_dir
        .as_ref()
        .and_then(|d| d.canonicalize().ok())
        .map(|d| d.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name: String = cfg
        .name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    Some(dir.join(format!("{name}-{:016x}.json", fnv1a(folder.as_bytes()))))
}

/// The cache at `path`, or an empty one when there is none or it cannot be
/// read (it is only a cache).
pub(super) fn load(path: &std::path::Path) -> SomCache {
    SomCache::load(path).unwrap_or_else(|e| {
        tracing::debug!("function cache {} not used: {e}", path.display());
        SomCache::new()
    })
}

/// Saves `cache` at `path`; a failure is logged, not an error (the next
/// start reads the functions again).
pub(super) fn save(path: &std::path::Path, cache: &SomCache) {
    if let Err(e) = cache.save(path) {
        tracing::debug!("function cache {} not saved: {e}", path.display());
    }
}

/// FNV-1a, 64 bits: a file name from a folder's path that stays the same
/// across builds (std's hasher may not).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}
