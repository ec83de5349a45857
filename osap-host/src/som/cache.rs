//! What a host keeps of the functions it read, between runs: for each
//! build of runtime it met ([`BuildIdentity`]: type, version, build key,
//! function-set id and port count), its ports and its built functions'
//! signatures, which are most of what a refresh reads.
//!
//! A runtime is trusted to be such a build only by what it reports in
//! runtime information, which every scan asks anyway: its function-set id
//! covers every built function's name, inputs and outputs in port order,
//! so a runtime with other functions reports another id and is read in
//! full. A runtime that reports none (id 0: a host, a hub, older firmware)
//! is never taken from the cache. What changes while a runtime runs (modes,
//! pipes, blocks made at run time) is always read again.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::model::{Som, SomArg};
use crate::error::JsonError;
use crate::map::{BuildIdentity, PortRecord};
use crate::netrunner::KnownPorts;
use pipes_core::function::FUNCTION_PORT_TYPE;

/// Layout version of a saved cache.
pub const CACHE_VERSION: u32 = 1;

/// A built function's signature as read from it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub(super) struct CachedSignature {
    /// Its control port.
    pub port: u16,
    pub name: String,
    /// The first sentence of its docs.
    pub summary: String,
    pub inputs: Vec<SomArg>,
    pub outputs: Vec<SomArg>,
}

/// One build's ports and built functions.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
struct CachedBuild {
    identity: BuildIdentity,
    ports: Vec<PortRecord>,
    functions: Vec<CachedSignature>,
}

/// Builds of runtimes met before, with their ports and built functions'
/// signatures (see the [module docs](self)); kept in a JSON file between
/// runs ([`load`](Self::load), [`save`](Self::save)) and used by
/// [`Manager::refresh_cached`](super::Manager::refresh_cached).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SomCache {
    version: u32,
    builds: Vec<CachedBuild>,
}

impl SomCache {
    /// An empty cache.
    pub fn new() -> SomCache {
        SomCache {
            version: CACHE_VERSION,
            builds: Vec::new(),
        }
    }

    /// The cache saved at `path`; empty if there is none. A file that
    /// cannot be read as a cache is an error (the caller may start
    /// afresh).
    pub fn load(path: &Path) -> Result<SomCache, JsonError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(_) => return Ok(SomCache::new()),
        };
        let cache: SomCache = serde_json::from_str(&text)?;
        if cache.version != CACHE_VERSION {
            return Err(JsonError::Version {
                what: "function cache",
                found: cache.version,
                supported: CACHE_VERSION,
            });
        }
        Ok(cache)
    }

    /// Saves the cache at `path` (its folder made if missing), whole or
    /// not at all: written beside it, then renamed over it.
    pub fn save(&self, path: &Path) -> std::io::Result<()> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        let text = serde_json::to_string(self).map_err(std::io::Error::other)?;
        let tmp = path.with_extension(format!("tmp{}", std::process::id()));
        std::fs::write(&tmp, text)?;
        std::fs::rename(&tmp, path)
    }

    /// How many builds it knows.
    pub fn builds(&self) -> usize {
        self.builds.len()
    }

    /// The ports of every build it knows, for [`crate::netrunner::scan_known`].
    pub fn known_ports(&self) -> KnownPorts {
        self.builds
            .iter()
            .map(|b| (b.identity.clone(), b.ports.clone()))
            .collect()
    }

    /// The signature of the built function at `port` of build `identity`.
    pub(super) fn signature(
        &self,
        identity: &BuildIdentity,
        port: u16,
    ) -> Option<&CachedSignature> {
        let build = self.builds.iter().find(|b| b.identity == *identity)?;
        build.functions.iter().find(|f| f.port == port)
    }

    /// Learns every build in `som` that it can: a runtime that reports a
    /// function-set id, all of whose ports and built functions were read.
    /// Returns whether anything new was learnt.
    pub fn learn(&mut self, som: &Som) -> bool {
        let mut learnt: BTreeMap<BuildIdentity, CachedBuild> = BTreeMap::new();
        for rt in &som.runtimes {
            let Some(identity) = rt.record.build_identity() else {
                continue;
            };
            if learnt.contains_key(&identity) || self.builds.iter().any(|b| b.identity == identity)
            {
                continue;
            }
            let built: Vec<u16> = rt
                .record
                .ports
                .iter()
                .filter(|p| p.type_name == FUNCTION_PORT_TYPE)
                .map(|p| p.index)
                .collect();
            let functions: Vec<CachedSignature> = built
                .iter()
                .filter_map(|&port| rt.functions.iter().find(|f| f.port == port))
                .map(|f| CachedSignature {
                    port: f.port,
                    name: f.name.clone(),
                    summary: f.summary.clone(),
                    inputs: f.inputs.clone(),
                    outputs: f.outputs.clone(),
                })
                .collect();
            // A function that did not answer: learn the build another time.
            if functions.len() != built.len() {
                continue;
            }
            learnt.insert(
                identity.clone(),
                CachedBuild {
                    identity,
                    ports: rt.record.ports.clone(),
                    functions,
                },
            );
        }
        let any = !learnt.is_empty();
        self.builds.extend(learnt.into_values());
        any
    }
}
