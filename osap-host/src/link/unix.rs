//! Unix domain socket links: a framed byte stream (`docs/protocol.md` §5)
//! over a Unix stream socket, as a client that reconnects or as a listener
//! that accepts. Links have type `unix` and are named by the socket path.
//!
//! Unix sockets never leave the machine, so there is nothing to refuse; the
//! socket file's permissions decide who may connect.

use super::stream::{
    link_error, Accept, LinkHandle, ListenAddr, ListenOptions, Listener, StreamLimits,
};
use super::LinkConfig;
use crate::runtime::Host;
use crate::HostError;
use std::io;
use std::path::Path;
use tokio::net::{UnixListener, UnixStream};

/// Connects to the socket at `path`, once.
async fn dial(path: &Path) -> Result<UnixStream, HostError> {
    UnixStream::connect(path).await.map_err(|e| {
        let hint = match e.kind() {
            io::ErrorKind::NotFound => "no such socket (is the peer running?)".to_string(),
            io::ErrorKind::ConnectionRefused => {
                "connection refused: the socket is left over from a peer that stopped".to_string()
            }
            _ => e.to_string(),
        };
        link_error(
            format!("cannot connect to {}", path.display()),
            e.kind(),
            hint,
        )
    })
}

/// Connects to the Unix socket at `path` and adds the connection to `host`
/// as a link of type `unix`. If the connection is lost the link is marked
/// closed and the task reconnects, with backoff from 100 ms to 2 s, until
/// the listener is back.
///
/// Fails, without adding a link, if the first connection cannot be made.
pub async fn connect(host: &Host, path: impl AsRef<Path>) -> Result<LinkHandle, HostError> {
    let path = path.as_ref().to_path_buf();
    let stream = dial(&path).await?;
    let name = path.display().to_string();
    let (index, io) = host.add_link(LinkConfig::new("unix", &name)).await?;
    Ok(LinkHandle::spawn_client(
        host,
        index,
        io,
        None,
        stream,
        move || {
            let path = path.clone();
            async move { dial(&path).await }
        },
        StreamLimits::CLIENT,
    ))
}

/// Listens on a Unix socket at `path` and gives each connection a link of
/// `host` (see [`Listener`]). A socket file left over from a listener that
/// stopped without cleaning up is replaced; one that a running listener
/// answers on, or a path that is not a socket, is an error. The socket file
/// is removed when the listener is dropped.
pub async fn listen(host: &Host, path: impl AsRef<Path>) -> Result<Listener, HostError> {
    let path = path.as_ref().to_path_buf();
    remove_stale(&path)?;
    let listener = UnixListener::bind(&path).map_err(|e| {
        link_error(
            format!("cannot listen on {}", path.display()),
            e.kind(),
            e.to_string(),
        )
    })?;
    Ok(Listener::spawn(
        host,
        Unix {
            listener,
            name: path.display().to_string(),
        },
        ListenAddr::Unix(path.clone()),
        "unix",
        Some(path),
        ListenOptions::default(),
    ))
}

/// Removes a socket file at `path` that nothing listens on any more.
fn remove_stale(path: &Path) -> Result<(), HostError> {
    use std::os::unix::fs::FileTypeExt;
    let context = || format!("cannot listen on {}", path.display());
    let Ok(meta) = std::fs::symlink_metadata(path) else {
        return Ok(());
    };
    if !meta.file_type().is_socket() {
        return Err(link_error(
            context(),
            io::ErrorKind::AlreadyExists,
            "the path exists and is not a socket; choose another path".into(),
        ));
    }
    match std::os::unix::net::UnixStream::connect(path) {
        Ok(_) => Err(link_error(
            context(),
            io::ErrorKind::AddrInUse,
            "another listener is running on this socket".into(),
        )),
        Err(_) => {
            tracing::info!("unix: removing stale socket {}", path.display());
            std::fs::remove_file(path).map_err(|e| HostError::Io {
                context: format!("removing stale socket {}", path.display()),
                source: e,
            })
        }
    }
}

/// A Unix listener as the generic listener wants it.
struct Unix {
    listener: UnixListener,
    name: String,
}

impl Accept for Unix {
    type Stream = UnixStream;

    async fn accept(&mut self) -> io::Result<(UnixStream, String)> {
        let (stream, _) = self.listener.accept().await?;
        Ok((stream, self.name.clone()))
    }
}
