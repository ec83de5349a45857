//! The zenoh configuration of a bridge or a client, and the rule that keeps
//! a machine off the network unless its peers must prove who they are.
//!
//! - A bridge listens on `tcp/127.0.0.1:7447` unless told otherwise.
//! - Multicast scouting is off unless the config file turns it on.
//! - Every endpoint a bridge listens on or connects to is on loopback,
//!   or is `tls/…` with user/password authentication or mutual TLS
//!   configured. Anything else is refused before the session opens.

use std::net::IpAddr;
use std::path::{Path, PathBuf};

/// Where a bridge listens when neither the options nor the config file
/// say: loopback, zenoh's usual port.
pub const DEFAULT_LISTEN: &str = "tcp/127.0.0.1:7447";

/// Why a configuration was refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The config file could not be read or parsed.
    #[error("zenoh config {path}: {reason}")]
    File {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// zenoh refused a value.
    #[error("zenoh config: {0}")]
    Zenoh(String),
    /// An endpoint would expose the machine without authentication.
    #[error("{endpoint}: {reason}")]
    Exposed {
        /// The endpoint.
        endpoint: String,
        /// Why it is refused, and what would make it acceptable.
        reason: String,
    },
}

/// The zenoh options of `osap bridge` and `osap fleet`.
#[derive(Debug, Clone, Default)]
pub struct ZenohOptions {
    /// Endpoints to listen on (`--zenoh-listen`); they replace the file's.
    pub listen: Vec<String>,
    /// Endpoints to connect to (`--zenoh-connect`); they replace the file's.
    pub connect: Vec<String>,
    /// A zenoh config file (`--zenoh-config`: JSON5, JSON or YAML).
    pub file: Option<PathBuf>,
}

/// Which keys a config file sets itself, so that the bridge's defaults
/// give way to them.
#[derive(Debug, Default)]
struct FileSets {
    listen: bool,
    multicast: bool,
}

fn read_file(path: &Path) -> Result<(zenoh::Config, FileSets), ConfigError> {
    let bad = |reason: String| ConfigError::File {
        path: path.to_path_buf(),
        reason,
    };
    let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
    let raw: serde_json::Value = match path.extension().and_then(|e| e.to_str()) {
        Some("yaml" | "yml") => serde_yaml::from_str(&text).map_err(|e| bad(e.to_string()))?,
        _ => json5::from_str(&text).map_err(|e| bad(e.to_string()))?,
    };
    let sets = FileSets {
        listen: raw.pointer("/listen/endpoints").is_some(),
        multicast: raw.pointer("/scouting/multicast/enabled").is_some(),
    };
    let config = zenoh::Config::from_file(path).map_err(|e| bad(e.to_string()))?;
    Ok((config, sets))
}

fn insert(
    config: &mut zenoh::Config,
    key: &str,
    value: serde_json::Value,
) -> Result<(), ConfigError> {
    config
        .insert_json5(key, &value.to_string())
        .map_err(|e| ConfigError::Zenoh(format!("{key}: {e}")))
}

/// Every endpoint of a mode-dependent endpoint list (an array, or one per
/// mode).
fn endpoints(config: &zenoh::Config, key: &str) -> Vec<String> {
    let Ok(json) = config.get_json(key) else {
        return Vec::new();
    };
    let value: serde_json::Value = serde_json::from_str(&json).unwrap_or_default();
    let mut out = Vec::new();
    let mut take = |v: &serde_json::Value| {
        if let Some(items) = v.as_array() {
            out.extend(items.iter().filter_map(|e| e.as_str().map(String::from)));
        }
    };
    match &value {
        serde_json::Value::Object(per_mode) => per_mode.values().for_each(&mut take),
        other => take(other),
    }
    out
}

fn get_str(config: &zenoh::Config, key: &str) -> Option<String> {
    let json = config.get_json(key).ok()?;
    match serde_json::from_str::<serde_json::Value>(&json).ok()? {
        serde_json::Value::String(s) if !s.is_empty() => Some(s),
        serde_json::Value::Bool(true) => Some("true".into()),
        _ => None,
    }
}

/// Whether an endpoint's address is on this computer.
fn on_loopback(address: &str) -> bool {
    // host:port, [v6]:port, or a bare host.
    let host = match address.rsplit_once(':') {
        Some((h, port)) if port.chars().all(|c| c.is_ascii_digit()) => h,
        _ => address,
    };
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host.eq_ignore_ascii_case("localhost")
        || host.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

/// Checks that no endpoint of `config` exposes the machine to peers that
/// did not prove who they are (see the module docs).
pub fn check_exposure(config: &zenoh::Config) -> Result<(), ConfigError> {
    let usrpwd = get_str(config, "transport/auth/usrpwd/user").is_some()
        && get_str(config, "transport/auth/usrpwd/password").is_some()
        || get_str(config, "transport/auth/usrpwd/dictionary_file").is_some();
    let mtls = get_str(config, "transport/link/tls/enable_mtls").is_some();
    let listen = endpoints(config, "listen/endpoints");
    let connect = endpoints(config, "connect/endpoints");
    for endpoint in listen.iter().chain(&connect) {
        // proto/address[?metadata][#config]
        let bare = endpoint.split(['?', '#']).next().unwrap_or(endpoint);
        let (proto, address) = bare.split_once('/').unwrap_or(("", bare));
        let refuse = |reason: &str| {
            Err(ConfigError::Exposed {
                endpoint: endpoint.clone(),
                reason: reason.into(),
            })
        };
        match proto {
            "tcp" if on_loopback(address) => {}
            "tcp" => {
                return refuse(
                    "plain TCP off loopback would let anyone on the network drive the machine: use a tls/ endpoint with user/password authentication or mutual TLS in --zenoh-config (docs/fleet.md)",
                )
            }
            "tls" if on_loopback(address) || usrpwd || mtls => {}
            "tls" => {
                return refuse(
                    "TLS off loopback needs its peers authenticated: set transport.auth.usrpwd (user and password, or dictionary_file) or transport.link.tls.enable_mtls in --zenoh-config (docs/fleet.md)",
                )
            }
            _ => return refuse("only tcp/ (on loopback) and tls/ endpoints are built into osap"),
        }
    }
    Ok(())
}

impl ZenohOptions {
    fn base(&self) -> Result<(zenoh::Config, FileSets), ConfigError> {
        let (mut config, sets) = match &self.file {
            Some(path) => read_file(path)?,
            None => (zenoh::Config::default(), FileSets::default()),
        };
        insert(&mut config, "mode", "peer".into())?;
        if !sets.multicast {
            insert(&mut config, "scouting/multicast/enabled", false.into())?;
        }
        if !self.connect.is_empty() {
            insert(
                &mut config,
                "connect/endpoints",
                self.connect.clone().into(),
            )?;
        }
        Ok((config, sets))
    }

    /// A bridge's configuration: listening where told (by default
    /// [`DEFAULT_LISTEN`]), checked by [`check_exposure`].
    pub fn bridge_config(&self) -> Result<zenoh::Config, ConfigError> {
        let (mut config, sets) = self.base()?;
        if !self.listen.is_empty() {
            insert(&mut config, "listen/endpoints", self.listen.clone().into())?;
        } else if !sets.listen {
            insert(&mut config, "listen/endpoints", vec![DEFAULT_LISTEN].into())?;
        }
        check_exposure(&config)?;
        Ok(config)
    }

    /// A client's configuration (`osap fleet`, a script): it listens
    /// nowhere unless told, and connects where told (by default to
    /// [`DEFAULT_LISTEN`]).
    pub fn client_config(&self) -> Result<zenoh::Config, ConfigError> {
        let (mut config, sets) = self.base()?;
        if !self.listen.is_empty() {
            insert(&mut config, "listen/endpoints", self.listen.clone().into())?;
        } else if !sets.listen {
            insert(&mut config, "listen/endpoints", serde_json::json!([]))?;
        }
        if self.connect.is_empty() && endpoints(&config, "connect/endpoints").is_empty() {
            insert(
                &mut config,
                "connect/endpoints",
                vec![DEFAULT_LISTEN].into(),
            )?;
        }
        Ok(config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bridge(listen: &[&str], file: Option<&str>) -> Result<zenoh::Config, ConfigError> {
        let file = file.map(|text| {
            let path = std::env::temp_dir().join(format!(
                "osap-zenoh-{}-{}.json5",
                std::process::id(),
                text.len()
            ));
            std::fs::write(&path, text).unwrap();
            path
        });
        let options = ZenohOptions {
            listen: listen.iter().map(|s| s.to_string()).collect(),
            connect: Vec::new(),
            file: file.clone(),
        };
        let result = options.bridge_config();
        if let Some(f) = file {
            let _ = std::fs::remove_file(f);
        }
        result
    }

    #[test]
    fn a_bridge_listens_on_loopback_by_default_without_multicast() {
        let c = bridge(&[], None).unwrap();
        assert_eq!(endpoints(&c, "listen/endpoints"), [DEFAULT_LISTEN]);
        assert_eq!(c.get_json("scouting/multicast/enabled").unwrap(), "false");
        for ok in ["tcp/127.0.0.1:7500", "tcp/[::1]:7500", "tcp/localhost:7500"] {
            bridge(&[ok], None).unwrap();
        }
    }

    #[test]
    fn off_loopback_needs_tls_and_authentication() {
        for exposed in ["tcp/0.0.0.0:7447", "tcp/192.168.1.5:7447", "tcp/[::]:7447"] {
            let e = bridge(&[exposed], None).unwrap_err();
            assert!(matches!(e, ConfigError::Exposed { .. }), "{e}");
            assert!(e.to_string().contains("tls/"), "{e}");
        }
        let e = bridge(&["tls/0.0.0.0:7447"], None).unwrap_err();
        assert!(e.to_string().contains("usrpwd"), "{e}");
        let e = bridge(&["udp/127.0.0.1:7447"], None).unwrap_err();
        assert!(e.to_string().contains("only tcp/"), "{e}");
        // With user/password authentication, or mutual TLS, it is allowed.
        bridge(
            &["tls/0.0.0.0:7447"],
            Some(r#"{ transport: { auth: { usrpwd: { user: "lab", password: "secret" } } } }"#),
        )
        .unwrap();
        bridge(
            &["tls/0.0.0.0:7447"],
            Some(r#"{ transport: { link: { tls: { enable_mtls: true } } } }"#),
        )
        .unwrap();
    }

    #[test]
    fn the_files_own_listen_and_multicast_are_kept_and_checked() {
        let c = bridge(
            &[],
            Some(r#"{ listen: { endpoints: ["tcp/127.0.0.1:7600"] }, scouting: { multicast: { enabled: true } } }"#),
        )
        .unwrap();
        assert_eq!(endpoints(&c, "listen/endpoints"), ["tcp/127.0.0.1:7600"]);
        assert_eq!(c.get_json("scouting/multicast/enabled").unwrap(), "true");
        let e = bridge(
            &[],
            Some(r#"{ listen: { endpoints: ["tcp/0.0.0.0:7600"] } }"#),
        )
        .unwrap_err();
        assert!(matches!(e, ConfigError::Exposed { .. }), "{e}");
        let e = bridge(&[], Some("{ not json5")).unwrap_err();
        assert!(matches!(e, ConfigError::File { .. }), "{e}");
    }

    #[test]
    fn a_client_listens_nowhere_and_connects_to_the_default() {
        let c = ZenohOptions::default().client_config().unwrap();
        assert!(endpoints(&c, "listen/endpoints").is_empty());
        assert_eq!(endpoints(&c, "connect/endpoints"), [DEFAULT_LISTEN]);
    }
}
