//! Routes: the forwarding instructions from one runtime to another.
//!
//! A [`Route`] holds only the forwarding hops (`link_forward`, `bus_forward`)
//! plus the smallest MTU known along them; the terminal instruction
//! (`port_handle` or `system_msg`) is added when a packet is written. An empty
//! route addresses the runtime itself.

use crate::packet::{Instruction, PacketError, HEADER_LEN, MTU_OFFSET, PTR_OFFSET, TTL_OFFSET};

/// Largest number of forwarding-instruction bytes a route may hold.
///
/// 32 bytes is 32 link hops, far deeper than any machine network, while
/// keeping a route small enough to copy freely on a microcontroller.
pub const MAX_ROUTE_LEN: usize = 32;

/// MTU of a route whose links have not been measured yet: each runtime limits
/// the packet to its own buffer and link MTUs instead.
pub const MTU_UNKNOWN: u16 = u16::MAX;

/// A source route: forwarding instructions to walk, in order.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Route {
    bytes: [u8; MAX_ROUTE_LEN],
    len: u8,
    mtu: u16,
}

impl Default for Route {
    fn default() -> Self {
        Route::local()
    }
}

impl core::fmt::Debug for Route {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let mut list = f.debug_list();
        for hop in self.hops() {
            list.entry(&hop);
        }
        list.finish()?;
        if self.mtu != MTU_UNKNOWN {
            write!(f, " mtu {}", self.mtu)?;
        }
        Ok(())
    }
}

/// Compact form: `local`, or hops such as `[L0 L2 B1.255]` (link 0, link 2,
/// bus 1 drop 255).
impl core::fmt::Display for Route {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        if self.is_empty() {
            return f.write_str("local");
        }
        f.write_str("[")?;
        for (i, hop) in self.hops().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            match hop {
                Instruction::LinkForward(l) => write!(f, "L{l}")?,
                Instruction::BusForward { bus, drop } => write!(f, "B{bus}.{drop}")?,
                other => write!(f, "{other:?}")?,
            }
        }
        f.write_str("]")
    }
}

impl Route {
    /// The empty route: a port in the same runtime.
    pub const fn local() -> Self {
        Route {
            bytes: [0; MAX_ROUTE_LEN],
            len: 0,
            mtu: MTU_UNKNOWN,
        }
    }

    /// A route through the given link indices, in order.
    pub fn through_links(links: &[u8]) -> Result<Self, PacketError> {
        let mut route = Route::local();
        for &link in links {
            route.push(Instruction::LinkForward(link))?;
        }
        Ok(route)
    }

    /// Parses forwarding instructions from `bytes`; any terminal instruction,
    /// truncated instruction or out-of-range field is an error.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, PacketError> {
        let mut route = Route::local();
        let mut rest = bytes;
        while !rest.is_empty() {
            let ins = Instruction::decode(rest)?;
            route.push(ins)?;
            rest = &rest[ins.encoded_len()..];
        }
        Ok(route)
    }

    /// Appends one forwarding instruction.
    pub fn push(&mut self, hop: Instruction) -> Result<(), PacketError> {
        if hop.is_terminal() {
            return Err(PacketError::UnexpectedInstruction);
        }
        let start = self.len as usize;
        let end = start + hop.encoded_len();
        if end > MAX_ROUTE_LEN {
            return Err(PacketError::RouteTooLong);
        }
        hop.encode(&mut self.bytes[start..end])?;
        self.len = end as u8;
        Ok(())
    }

    /// This route extended by one hop (for building routes during a scan).
    pub fn with_hop(mut self, hop: Instruction) -> Result<Self, PacketError> {
        self.push(hop)?;
        Ok(self)
    }

    /// The same route with the given MTU.
    pub const fn with_mtu(mut self, mtu: u16) -> Self {
        self.mtu = mtu;
        self
    }

    /// Smallest MTU along the route, or [`MTU_UNKNOWN`].
    pub const fn mtu(&self) -> u16 {
        self.mtu
    }

    /// The encoded forwarding instructions.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len as usize]
    }

    /// Number of encoded bytes.
    pub const fn len(&self) -> usize {
        self.len as usize
    }

    /// Whether this is the local (empty) route.
    pub const fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The hops, in walking order.
    pub fn hops(&self) -> Hops<'_> {
        Hops {
            rest: self.as_bytes(),
        }
    }

    /// Number of hops.
    pub fn hop_count(&self) -> usize {
        self.hops().count()
    }

    /// The hops in reverse order (the mtu is kept: links are symmetric).
    ///
    /// This is how a route walked by a packet becomes the way back: the
    /// runtime rewrote each hop it crossed into the hop that returns, so only
    /// the order is left to flip.
    pub fn reversed(&self) -> Self {
        let mut out = Route::local().with_mtu(self.mtu);
        let mut end = self.len as usize;
        // Instructions delimit themselves only from the front, so find their
        // start offsets first, then copy them out back to front.
        let mut starts = [0u8; MAX_ROUTE_LEN];
        let mut count = 0;
        let mut at = 0usize;
        while at < end {
            starts[count] = at as u8;
            count += 1;
            at += Instruction::len_from_first_byte(self.bytes[at]);
        }
        let mut write = 0usize;
        for i in (0..count).rev() {
            let start = starts[i] as usize;
            let len = end - start;
            out.bytes[write..write + len].copy_from_slice(&self.bytes[start..end]);
            write += len;
            end = start;
        }
        out.len = write as u8;
        out
    }

    /// Number of bytes a packet on this route needs before its payload, with
    /// the given terminal instruction.
    pub fn header_len(&self, terminal: Instruction) -> usize {
        HEADER_LEN + self.len() + terminal.encoded_len()
    }

    /// Writes a fresh packet `[header][route][terminal][payload]` into `out`
    /// and returns its length.
    ///
    /// `mtu` is written into the header as given; callers pass the smaller of
    /// the route MTU and their own limits.
    pub fn write_packet(
        &self,
        out: &mut [u8],
        terminal: Instruction,
        ttl: u16,
        mtu: u16,
        payload: &[u8],
    ) -> Result<usize, PacketError> {
        let start = self.write_header(out, terminal, ttl, mtu)?;
        let end = start + payload.len();
        if end > usize::from(mtu) {
            return Err(PacketError::TooLong);
        }
        out.get_mut(start..end)
            .ok_or(PacketError::TooLong)?
            .copy_from_slice(payload);
        Ok(end)
    }

    /// Writes everything but the payload, returning the payload's offset.
    pub fn write_header(
        &self,
        out: &mut [u8],
        terminal: Instruction,
        ttl: u16,
        mtu: u16,
    ) -> Result<usize, PacketError> {
        if !terminal.is_terminal() {
            return Err(PacketError::UnexpectedInstruction);
        }
        let route_end = HEADER_LEN + self.len();
        let header_end = route_end + terminal.encoded_len();
        if header_end > out.len() || header_end > usize::from(mtu) {
            return Err(PacketError::TooLong);
        }
        out[PTR_OFFSET] = HEADER_LEN as u8;
        out[TTL_OFFSET..TTL_OFFSET + 2].copy_from_slice(&ttl.to_le_bytes());
        out[MTU_OFFSET..MTU_OFFSET + 2].copy_from_slice(&mtu.to_le_bytes());
        out[HEADER_LEN..route_end].copy_from_slice(self.as_bytes());
        terminal.encode(&mut out[route_end..])?;
        Ok(header_end)
    }
}

/// Iterator over the hops of a [`Route`].
#[derive(Debug, Clone)]
pub struct Hops<'a> {
    rest: &'a [u8],
}

impl Iterator for Hops<'_> {
    type Item = Instruction;

    fn next(&mut self) -> Option<Instruction> {
        // A Route only ever holds validated instructions, so decoding here
        // cannot fail; stop rather than panic if it somehow did.
        let ins = Instruction::decode(self.rest).ok()?;
        self.rest = self.rest.get(ins.encoded_len()..).unwrap_or(&[]);
        Some(ins)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::packet::Packet;

    #[test]
    fn reversal_flips_mixed_hops() {
        let mut r = Route::local();
        r.push(Instruction::LinkForward(1)).unwrap();
        r.push(Instruction::BusForward { bus: 2, drop: 9 }).unwrap();
        r.push(Instruction::LinkForward(4)).unwrap();
        let back = r.reversed();
        let hops: heapless::Vec<Instruction, 4> = back.hops().collect();
        assert_eq!(
            hops.as_slice(),
            &[
                Instruction::LinkForward(4),
                Instruction::BusForward { bus: 2, drop: 9 },
                Instruction::LinkForward(1)
            ]
        );
        assert_eq!(back.reversed(), r);
    }

    #[test]
    fn route_refuses_terminals_and_overflow() {
        let mut r = Route::local();
        assert_eq!(
            r.push(Instruction::SystemMsg(0)),
            Err(PacketError::UnexpectedInstruction)
        );
        for _ in 0..MAX_ROUTE_LEN {
            r.push(Instruction::LinkForward(0)).unwrap();
        }
        assert_eq!(
            r.push(Instruction::LinkForward(0)),
            Err(PacketError::RouteTooLong)
        );
        assert_eq!(
            Route::from_bytes(&[0x41, 0xC0, 0, 0]),
            Err(PacketError::UnexpectedInstruction)
        );
        assert_eq!(Route::from_bytes(&[0x81]), Err(PacketError::Truncated));
    }

    #[test]
    fn write_packet_layout() {
        let route = Route::through_links(&[1]).unwrap();
        let mut buf = [0u8; 64];
        let n = route
            .write_packet(
                &mut buf,
                Instruction::PortHandle { src: 3, dst: 0 },
                1000,
                256,
                &[0xAA],
            )
            .unwrap();
        assert_eq!(
            &buf[..n],
            &[5, 0xE8, 0x03, 0x00, 0x01, 0x41, 0xC0, 0x18, 0x00, 0xAA]
        );
        let p = Packet::new_checked(&buf[..n]).unwrap();
        assert_eq!(p.instruction(), Ok(Instruction::LinkForward(1)));
    }

    #[test]
    fn write_packet_respects_mtu_and_buffer() {
        let route = Route::local();
        let mut small = [0u8; 9];
        let t = Instruction::PortHandle { src: 1, dst: 1 };
        assert_eq!(
            route.write_packet(&mut small, t, 0, 256, &[1, 2]),
            Err(PacketError::TooLong)
        );
        let mut buf = [0u8; 64];
        assert_eq!(
            route.write_packet(&mut buf, t, 0, 9, &[1, 2]),
            Err(PacketError::TooLong)
        );
        assert_eq!(route.write_packet(&mut buf, t, 0, 10, &[1, 2]), Ok(10));
    }
}
