//! The packet header and route instructions, read and written in place.
//!
//! A packet is `[ptr][ttl u16][mtu u16][route instructions...][payload]`.
//! `ptr` is the offset of the next instruction to execute. Instructions before
//! `ptr` have already been walked and were rewritten, hop by hop, into the way
//! back; see [`crate::route`] for reversal.

use core::fmt;

/// Offset of the instruction pointer byte.
pub const PTR_OFFSET: usize = 0;
/// Offset of the little-endian `u16` time-to-live, in microseconds.
pub const TTL_OFFSET: usize = 1;
/// Offset of the little-endian `u16` route MTU, in bytes.
pub const MTU_OFFSET: usize = 3;
/// Length of the fixed header; also the offset of the first instruction.
pub const HEADER_LEN: usize = 5;
/// The smallest well-formed packet: a header and one system message.
pub const MIN_PACKET_LEN: usize = HEADER_LEN + 1;

/// Number of link gateways addressable by `link_forward` (6 bits).
pub const MAX_LINKS: u8 = 64;
/// Number of buses addressable by `bus_forward` (6 bits).
pub const MAX_BUSES: u8 = 64;
/// Number of system message codes (6 bits).
pub const MAX_SYSTEM_CODES: u8 = 64;
/// Number of ports addressable by `port_handle` (11 bits).
pub const MAX_PORTS: u16 = 2048;
/// The `bus_forward` drop address that means every drop on the bus.
pub const BUS_BROADCAST: u8 = 255;

const OP_SYSTEM: u8 = 0b00;
const OP_LINK: u8 = 0b01;
const OP_BUS: u8 = 0b10;
const OP_PORT: u8 = 0b11;

/// Everything that can be wrong with a packet or an instruction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PacketError {
    /// The bytes end before the header, an instruction, or a field does.
    Truncated,
    /// `ptr` points into the header or past the end of the packet.
    BadPointer,
    /// An instruction field is out of its encodable range.
    FieldOutOfRange,
    /// The instruction at `ptr` is not one this step can execute.
    UnexpectedInstruction,
    /// The packet is longer than a buffer, a link MTU, or the header's `mtu`.
    TooLong,
    /// A route has more instruction bytes than [`crate::route::MAX_ROUTE_LEN`].
    RouteTooLong,
}

impl fmt::Display for PacketError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            PacketError::Truncated => "packet is truncated",
            PacketError::BadPointer => "instruction pointer is out of range",
            PacketError::FieldOutOfRange => "instruction field is out of range",
            PacketError::UnexpectedInstruction => "unexpected instruction at pointer",
            PacketError::TooLong => "packet is longer than allowed",
            PacketError::RouteTooLong => "route is too long",
        })
    }
}

/// One route instruction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Instruction {
    /// Terminal: handled by the runtime itself (time sync and future codes).
    SystemMsg(u8),
    /// Forward out of the link gateway with this index.
    LinkForward(u8),
    /// Forward onto a bus, to one drop or to all (reserved; no bus driver yet).
    BusForward {
        /// Index of the bus gateway.
        bus: u8,
        /// Drop address on the bus; [`BUS_BROADCAST`] for all.
        drop: u8,
    },
    /// Terminal: deliver the payload from port `src` to local port `dst`.
    PortHandle {
        /// Port index the packet was sent from, in the sending runtime.
        src: u16,
        /// Port index to deliver to, in this runtime.
        dst: u16,
    },
}

impl Instruction {
    /// Decodes the instruction at the start of `bytes`.
    pub fn decode(bytes: &[u8]) -> Result<Instruction, PacketError> {
        let first = *bytes.first().ok_or(PacketError::Truncated)?;
        let arg = first & 0x3f;
        Ok(match first >> 6 {
            OP_SYSTEM => Instruction::SystemMsg(arg),
            OP_LINK => Instruction::LinkForward(arg),
            OP_BUS => {
                let drop = *bytes.get(1).ok_or(PacketError::Truncated)?;
                Instruction::BusForward { bus: arg, drop }
            }
            _ => {
                let (b1, b2) = match bytes {
                    [_, b1, b2, ..] => (*b1, *b2),
                    _ => return Err(PacketError::Truncated),
                };
                let word = u32::from(arg) << 16 | u32::from(b1) << 8 | u32::from(b2);
                Instruction::PortHandle {
                    src: ((word >> 11) & 0x7ff) as u16,
                    dst: (word & 0x7ff) as u16,
                }
            }
        })
    }

    /// Number of bytes this instruction occupies on the wire.
    pub const fn encoded_len(&self) -> usize {
        match self {
            Instruction::SystemMsg(_) | Instruction::LinkForward(_) => 1,
            Instruction::BusForward { .. } => 2,
            Instruction::PortHandle { .. } => 3,
        }
    }

    /// Number of bytes of the instruction whose first byte is `first`.
    pub const fn len_from_first_byte(first: u8) -> usize {
        match first >> 6 {
            OP_SYSTEM | OP_LINK => 1,
            OP_BUS => 2,
            _ => 3,
        }
    }

    /// Whether a route ends at this instruction.
    pub const fn is_terminal(&self) -> bool {
        matches!(
            self,
            Instruction::SystemMsg(_) | Instruction::PortHandle { .. }
        )
    }

    /// Whether every field fits its bit width.
    pub const fn is_valid(&self) -> bool {
        match *self {
            Instruction::SystemMsg(code) => code < MAX_SYSTEM_CODES,
            Instruction::LinkForward(link) => link < MAX_LINKS,
            Instruction::BusForward { bus, .. } => bus < MAX_BUSES,
            Instruction::PortHandle { src, dst } => src < MAX_PORTS && dst < MAX_PORTS,
        }
    }

    /// Writes the instruction at the start of `out`, returning its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, PacketError> {
        if !self.is_valid() {
            return Err(PacketError::FieldOutOfRange);
        }
        let len = self.encoded_len();
        let dst = out.get_mut(..len).ok_or(PacketError::Truncated)?;
        match *self {
            Instruction::SystemMsg(code) => dst[0] = OP_SYSTEM << 6 | code,
            Instruction::LinkForward(link) => dst[0] = OP_LINK << 6 | link,
            Instruction::BusForward { bus, drop } => {
                dst[0] = OP_BUS << 6 | bus;
                dst[1] = drop;
            }
            Instruction::PortHandle { src, dst: d } => {
                let word = u32::from(OP_PORT) << 22 | u32::from(src) << 11 | u32::from(d);
                dst.copy_from_slice(&word.to_be_bytes()[1..]);
            }
        }
        Ok(len)
    }
}

/// A read-only view of a packet whose header has been checked.
///
/// Construction checks that the header is present and `ptr` points at an
/// instruction inside the packet; every accessor is then infallible except
/// where it must decode further bytes.
#[derive(Debug, Clone, Copy)]
pub struct Packet<'a> {
    bytes: &'a [u8],
}

impl<'a> Packet<'a> {
    /// Checks the header of `bytes` and wraps them.
    pub fn new(bytes: &'a [u8]) -> Result<Self, PacketError> {
        if bytes.len() < MIN_PACKET_LEN {
            return Err(PacketError::Truncated);
        }
        let ptr = bytes[PTR_OFFSET] as usize;
        if ptr < HEADER_LEN || ptr >= bytes.len() {
            return Err(PacketError::BadPointer);
        }
        Ok(Packet { bytes })
    }

    /// The whole packet.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// Offset of the next instruction.
    pub fn ptr(&self) -> usize {
        self.bytes[PTR_OFFSET] as usize
    }

    /// Microseconds left until the packet's deadline, as last written.
    pub fn ttl(&self) -> u16 {
        u16::from_le_bytes([self.bytes[TTL_OFFSET], self.bytes[TTL_OFFSET + 1]])
    }

    /// Smallest link MTU along the route, as written by the sender.
    pub fn mtu(&self) -> u16 {
        u16::from_le_bytes([self.bytes[MTU_OFFSET], self.bytes[MTU_OFFSET + 1]])
    }

    /// The instruction at `ptr`.
    pub fn instruction(&self) -> Result<Instruction, PacketError> {
        Instruction::decode(&self.bytes[self.ptr()..])
    }

    /// The instructions already walked: the way back, in walking order.
    pub fn walked(&self) -> &'a [u8] {
        &self.bytes[HEADER_LEN..self.ptr()]
    }

    /// The bytes after the instruction at `ptr` (the payload, when that
    /// instruction is terminal).
    pub fn after_instruction(&self) -> Result<&'a [u8], PacketError> {
        let start = self.ptr() + self.instruction()?.encoded_len();
        self.bytes.get(start..).ok_or(PacketError::Truncated)
    }
}

/// Writes the `ttl` field of a packet buffer.
pub fn set_ttl(packet: &mut [u8], ttl: u16) -> Result<(), PacketError> {
    let dst = packet
        .get_mut(TTL_OFFSET..TTL_OFFSET + 2)
        .ok_or(PacketError::Truncated)?;
    dst.copy_from_slice(&ttl.to_le_bytes());
    Ok(())
}

/// Applies the ingest rewrite to a packet that just arrived: the forwarding
/// instruction at `ptr` is overwritten with `arrival`, the way back
/// (`link_forward(i)` for our link `i`, or `bus_forward` with our bus index and
/// the sender's drop), and `ptr` advances past it.
///
/// Returns the instruction that is now at `ptr`.
pub fn ingest_rewrite(packet: &mut [u8], arrival: Instruction) -> Result<Instruction, PacketError> {
    let view = Packet::new(packet)?;
    let ptr = view.ptr();
    let consumed = view.instruction()?;
    let matches_kind = matches!(
        (consumed, arrival),
        (Instruction::LinkForward(_), Instruction::LinkForward(_))
            | (
                Instruction::BusForward { .. },
                Instruction::BusForward { .. }
            )
    );
    if !matches_kind {
        return Err(PacketError::UnexpectedInstruction);
    }
    let len = arrival.encode(&mut packet[ptr..])?;
    let next = ptr + len;
    if next >= packet.len() {
        return Err(PacketError::BadPointer);
    }
    let next_instruction = Instruction::decode(&packet[next..])?;
    // next < packet.len() <= u8 range is guaranteed by the buffer sizes we
    // accept, but a huge host buffer must still not wrap the pointer.
    packet[PTR_OFFSET] = u8::try_from(next).map_err(|_| PacketError::BadPointer)?;
    Ok(next_instruction)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn port_handle_layout_matches_spec() {
        let mut b = [0u8; 3];
        Instruction::PortHandle { src: 1, dst: 2 }
            .encode(&mut b)
            .unwrap();
        // 0b11 << 22 | 1 << 11 | 2 = 0xC00802
        assert_eq!(b, [0xC0, 0x08, 0x02]);
        Instruction::PortHandle {
            src: 2047,
            dst: 2047,
        }
        .encode(&mut b)
        .unwrap();
        assert_eq!(b, [0xFF, 0xFF, 0xFF]);
    }

    #[test]
    fn single_byte_instructions() {
        let mut b = [0u8; 2];
        Instruction::LinkForward(5).encode(&mut b).unwrap();
        assert_eq!(b[0], 0x45);
        Instruction::SystemMsg(1).encode(&mut b).unwrap();
        assert_eq!(b[0], 0x01);
        Instruction::BusForward { bus: 3, drop: 255 }
            .encode(&mut b)
            .unwrap();
        assert_eq!(b, [0x83, 0xFF]);
    }

    #[test]
    fn out_of_range_fields_are_refused() {
        let mut b = [0u8; 3];
        for bad in [
            Instruction::LinkForward(64),
            Instruction::SystemMsg(64),
            Instruction::BusForward { bus: 64, drop: 0 },
            Instruction::PortHandle { src: 2048, dst: 0 },
            Instruction::PortHandle { src: 0, dst: 2048 },
        ] {
            assert_eq!(bad.encode(&mut b), Err(PacketError::FieldOutOfRange));
        }
    }

    #[test]
    fn truncated_instructions_are_errors() {
        assert_eq!(Instruction::decode(&[]), Err(PacketError::Truncated));
        assert_eq!(Instruction::decode(&[0x80]), Err(PacketError::Truncated));
        assert_eq!(Instruction::decode(&[0xC0, 0]), Err(PacketError::Truncated));
    }

    #[test]
    fn header_checks() {
        assert_eq!(
            Packet::new(&[5, 0, 0, 0]).unwrap_err(),
            PacketError::Truncated
        );
        assert_eq!(
            Packet::new(&[4, 0, 0, 0, 0, 0]).unwrap_err(),
            PacketError::BadPointer
        );
        assert_eq!(
            Packet::new(&[6, 0, 0, 0, 0, 0]).unwrap_err(),
            PacketError::BadPointer
        );
        let p = Packet::new(&[5, 0xe8, 0x03, 0x00, 0x01, 0x40, 0xC0, 0, 1]).unwrap();
        assert_eq!(p.ttl(), 1000);
        assert_eq!(p.mtu(), 256);
        assert_eq!(p.instruction(), Ok(Instruction::LinkForward(0)));
    }

    #[test]
    fn ingest_rewrites_the_hop_and_advances() {
        // link_forward(3) then port_handle(1 -> 2); arrives on our link 7.
        let mut pkt = [5, 0, 0, 0, 1, 0x43, 0xC0, 0x08, 0x02, 0xAA];
        let next = ingest_rewrite(&mut pkt, Instruction::LinkForward(7)).unwrap();
        assert_eq!(next, Instruction::PortHandle { src: 1, dst: 2 });
        assert_eq!(pkt[0], 6);
        assert_eq!(pkt[5], 0x47);
    }

    #[test]
    fn ingest_refuses_a_terminal_at_ptr() {
        let mut pkt = [5, 0, 0, 0, 1, 0xC0, 0x08, 0x02];
        assert_eq!(
            ingest_rewrite(&mut pkt, Instruction::LinkForward(0)),
            Err(PacketError::UnexpectedInstruction)
        );
        // A forward with nothing after it has no instruction to advance to.
        let mut pkt = [5, 0, 0, 0, 1, 0x41];
        assert_eq!(
            ingest_rewrite(&mut pkt, Instruction::LinkForward(0)),
            Err(PacketError::BadPointer)
        );
    }
}
