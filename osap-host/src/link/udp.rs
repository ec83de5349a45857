//! UDP links: one bare packet per datagram, no framing
//! (`docs/protocol.md` §5).
//!
//! A UDP link talks to one peer. Given the peer's address it is open from
//! the start; without one it waits for the first datagram and from then on
//! talks only to its sender. UDP has no connection, so a link never notices
//! that its peer went away: packets to a peer that is not there are lost
//! (and time out at the sender), and flow again when the peer is back.
//!
//! The local address must be loopback unless the caller explicitly allows
//! another, so a machine is never opened to a network by default. Links
//! have type `udp` and are named by the peer's address, or by the local
//! address when the peer is learnt from its first datagram.

use super::stream::{check_bind, link_error, LinkHandle, LinkState};
use super::LinkConfig;
use crate::runtime::Host;
use crate::{HostError, HOST_MTU};
use std::net::SocketAddr;
use tokio::net::UdpSocket;

pub use super::stream::loopback;

/// Largest datagram read; longer ones are cut by the OS.
const MAX_DATAGRAM: usize = 65_536;

/// Binds a UDP socket at `local` and adds it to `host` as a link to `peer`,
/// or, with `peer` `None`, to whoever sends the first datagram. `local`
/// should be [`loopback`]`(port)` (port 0 picks a free one;
/// [`LinkHandle::local_addr`] tells which); any other address is refused
/// unless `allow_remote` is true.
///
/// Received datagrams longer than the host MTU are dropped and counted as
/// frame errors; when the runtime's queue for the link is full, datagrams
/// are dropped and counted (`rx_dropped`), as UDP does.
pub async fn bind(
    host: &Host,
    local: SocketAddr,
    peer: Option<SocketAddr>,
    allow_remote: bool,
) -> Result<LinkHandle, HostError> {
    // UDP links carry no key: allow_remote alone opens them (docs/security.md).
    check_bind(local, allow_remote, true)?;
    let socket = UdpSocket::bind(local).await.map_err(|e| {
        link_error(
            format!("cannot bind UDP socket {local}"),
            e.kind(),
            e.to_string(),
        )
    })?;
    let bound = socket.local_addr().unwrap_or(local);
    if let Some(peer) = peer {
        socket.connect(peer).await.map_err(|e| {
            link_error(
                format!("cannot address UDP peer {peer}"),
                e.kind(),
                e.to_string(),
            )
        })?;
    }
    let name = peer.unwrap_or(bound).to_string();
    let (index, io) = host.add_link(LinkConfig::new("udp", &name)).await?;
    let initial = match peer {
        Some(_) => LinkState::Connected,
        None => LinkState::Disconnected {
            attempts: 0,
            reason: format!("waiting for the first datagram on {bound}"),
        },
    };
    Ok(LinkHandle::spawn(
        host,
        index,
        io,
        Some(bound),
        initial,
        move |io, state| async move {
            let mut peer = peer;
            if peer.is_some() {
                io.set_open(true);
            }
            let mut buf = vec![0u8; MAX_DATAGRAM];
            loop {
                tokio::select! {
                    received = socket.recv_from(&mut buf) => {
                        let (n, from) = match received {
                            Ok(r) => r,
                            Err(e) => {
                                // An ICMP "port unreachable" from a send to
                                // a peer that is not there, and the like.
                                tracing::debug!(link = %name, "udp receive: {e}");
                                continue;
                            }
                        };
                        let stamp = io.clock().now();
                        if peer.is_none() {
                            if let Err(e) = socket.connect(from).await {
                                tracing::warn!(link = %name, "udp: cannot answer {from}: {e}");
                                continue;
                            }
                            peer = Some(from);
                            io.set_open(true);
                            state.send_replace(LinkState::Connected);
                            tracing::info!("udp link {name}: talking to {from}");
                        }
                        match buf.get(..n) {
                            Some(packet) if n <= HOST_MTU => {
                                io.deliver_stamped(packet.to_vec(), stamp);
                            }
                            _ => {
                                io.count_frame_errors(1);
                                tracing::debug!(link = %name, len = n, "udp: datagram too long");
                            }
                        }
                    }
                    packet = io.next_tx(), if peer.is_some() => {
                        let Some(packet) = packet else { return };
                        if let Err(e) = socket.send(&packet).await {
                            tracing::debug!(link = %name, "udp send: {e}");
                        }
                    }
                }
            }
        },
    ))
}
