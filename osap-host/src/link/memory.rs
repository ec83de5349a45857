//! In-process links: two runtimes in one process joined by queues, with no
//! task in between.

use super::{ChannelLink, LinkConfig};
use crate::runtime::Host;
use crate::HostError;

/// Joins host `a` and host `b` with an in-process link; returns the link
/// index on each side.
pub async fn connect(a: &Host, b: &Host) -> Result<(u8, u8), HostError> {
    let config = LinkConfig::new("memory", "");
    let (mut la, io_a) = a.make_link(config.clone());
    let (mut lb, io_b) = b.make_link(config);
    ChannelLink::join(&mut la, &mut lb);
    let ia = a.attach_link(la).await?;
    let ib = b.attach_link(lb).await?;
    io_a.set_open(true);
    io_b.set_open(true);
    Ok((ia, ib))
}
