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
    Some(dir.join(format!(
        "{name}-{:016x}.json",
        folder_key(folder.as_bytes())
    )))
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

/// A file name from a folder's path that stays the same across builds
/// and platforms (std's hasher may not): its CRC-64.
fn folder_key(bytes: &[u8]) -> u64 {
    crc::Crc::<u64>::new(&crc::CRC_64_XZ).checksum(bytes)
}
