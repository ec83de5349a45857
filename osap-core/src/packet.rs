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
#[non_exhaustive]
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

impl core::error::Error for PacketError {}

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

/// A view of a packet in a buffer, in the style of smoltcp's `wire` types.
///
/// [`Packet::new_checked`] checks once that the header is present and that
/// `ptr` points at an instruction inside the packet; the getters then read
/// the header without checking it again, and only decode further bytes
/// where they must ([`Packet::instruction`], [`Packet::after_instruction`]).
/// Getters need `T: AsRef<[u8]>`; setters and the in-place ingest rewrite
/// need `T: AsMut<[u8]>` too, and keep the header valid.
///
/// A view made with [`Packet::new_unchecked`] skips the check: its getters
/// and setters panic on a buffer [`Packet::check_len`] would refuse.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packet<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Packet<T> {
    /// Wraps `buffer` without checking it (see [`Packet::check_len`]).
    pub const fn new_unchecked(buffer: T) -> Self {
        Packet { buffer }
    }

    /// Wraps `buffer` after [`Packet::check_len`]: the header is present
    /// and `ptr` points inside the packet, past the header.
    pub fn new_checked(buffer: T) -> Result<Self, PacketError> {
        let packet = Self::new_unchecked(buffer);
        packet.check_len()?;
        Ok(packet)
    }

    /// Checks that the buffer holds a header and at least one byte, and
    /// that `ptr` points past the header at a byte inside the buffer.
    ///
    /// Errors: [`PacketError::Truncated`] for a buffer shorter than
    /// [`MIN_PACKET_LEN`], [`PacketError::BadPointer`] for a `ptr` into
    /// the header or past the end.
    pub fn check_len(&self) -> Result<(), PacketError> {
        let bytes = self.buffer.as_ref();
        if bytes.len() < MIN_PACKET_LEN {
            return Err(PacketError::Truncated);
        }
        let ptr = bytes[PTR_OFFSET] as usize;
        if ptr < HEADER_LEN || ptr >= bytes.len() {
            return Err(PacketError::BadPointer);
        }
        Ok(())
    }

    /// The buffer, given back.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    /// The whole packet.
    pub fn as_bytes(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// Offset of the next instruction.
    #[inline]
    pub fn ptr(&self) -> usize {
        self.buffer.as_ref()[PTR_OFFSET] as usize
    }

    /// Microseconds left until the packet's deadline, as last written.
    #[inline]
    pub fn ttl(&self) -> u16 {
        let b = self.buffer.as_ref();
        u16::from_le_bytes([b[TTL_OFFSET], b[TTL_OFFSET + 1]])
    }

    /// Smallest link MTU along the route, as written by the sender.
    #[inline]
    pub fn mtu(&self) -> u16 {
        let b = self.buffer.as_ref();
        u16::from_le_bytes([b[MTU_OFFSET], b[MTU_OFFSET + 1]])
    }

    /// The instruction at `ptr`.
    ///
    /// Errors: [`PacketError::Truncated`] if the packet ends inside it.
    #[inline]
    pub fn instruction(&self) -> Result<Instruction, PacketError> {
        Instruction::decode(&self.buffer.as_ref()[self.ptr()..])
    }
}

impl<'a, T: AsRef<[u8]> + ?Sized> Packet<&'a T> {
    /// The instructions already walked: the way back, in walking order.
    pub fn walked(&self) -> &'a [u8] {
        let bytes = self.buffer.as_ref();
        &bytes[HEADER_LEN..bytes[PTR_OFFSET] as usize]
    }

    /// The bytes after the instruction at `ptr` (the payload, when that
    /// instruction is terminal).
    ///
    /// Errors: [`PacketError::Truncated`] if the packet ends inside that
    /// instruction.
    pub fn after_instruction(&self) -> Result<&'a [u8], PacketError> {
        let bytes = self.buffer.as_ref();
        let start = self.ptr() + self.instruction()?.encoded_len();
        bytes.get(start..).ok_or(PacketError::Truncated)
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> Packet<T> {
    /// Writes the `ttl` field.
    #[inline]
    pub fn set_ttl(&mut self, ttl: u16) {
        self.buffer.as_mut()[TTL_OFFSET..TTL_OFFSET + 2].copy_from_slice(&ttl.to_le_bytes());
    }

    /// Writes the `mtu` field.
    #[inline]
    pub fn set_mtu(&mut self, mtu: u16) {
        self.buffer.as_mut()[MTU_OFFSET..MTU_OFFSET + 2].copy_from_slice(&mtu.to_le_bytes());
    }

    /// Moves `ptr` to `ptr`, which must point past the header at a byte
    /// inside the packet; the packet is left as it was otherwise.
    ///
    /// Errors: [`PacketError::BadPointer`] for a pointer into the header,
    /// past the end, or beyond the one-byte field's range.
    pub fn set_ptr(&mut self, ptr: usize) -> Result<(), PacketError> {
        let len = self.buffer.as_ref().len();
        if ptr < HEADER_LEN || ptr >= len {
            return Err(PacketError::BadPointer);
        }
        self.buffer.as_mut()[PTR_OFFSET] =
            u8::try_from(ptr).map_err(|_| PacketError::BadPointer)?;
        Ok(())
    }

    /// The whole packet, to write.
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        self.buffer.as_mut()
    }

    /// Applies the ingest rewrite to a packet that just arrived: the
    /// forwarding instruction at `ptr` is overwritten with `arrival`, the way
    /// back (`link_forward(i)` for our link `i`, or `bus_forward` with our
    /// bus index and the sender's drop), and `ptr` advances past it.
    ///
    /// Returns the instruction that is now at `ptr`. On an error the packet
    /// is left unchanged.
    ///
    /// Errors: [`PacketError::UnexpectedInstruction`] if the instruction at
    /// `ptr` is not a forward of the same kind as `arrival`;
    /// [`PacketError::FieldOutOfRange`] for an `arrival` that cannot be
    /// encoded; [`PacketError::BadPointer`] or [`PacketError::Truncated`]
    /// if nothing whole follows the forward.
    pub fn ingest(&mut self, arrival: Instruction) -> Result<Instruction, PacketError> {
        let ptr = self.ptr();
        let consumed = self.instruction()?;
        let matches_kind = matches!(
            (consumed, arrival),
            (Instruction::LinkForward(_), Instruction::LinkForward(_))
                | (
                    Instruction::BusForward { .. },
                    Instruction::BusForward { .. }
                )
        );
        if !matches_kind || !arrival.is_valid() {
            return Err(if matches_kind {
                PacketError::FieldOutOfRange
            } else {
                PacketError::UnexpectedInstruction
            });
        }
        // Same kind, so the same length: the hop fits where `consumed` was.
        let next = ptr + arrival.encoded_len();
        let bytes = self.buffer.as_ref();
        if next >= bytes.len() {
            return Err(PacketError::BadPointer);
        }
        let next_instruction = Instruction::decode(&bytes[next..])?;
        // next < packet.len() <= u8 range is guaranteed by the buffer sizes
        // we accept, but a huge host buffer must still not wrap the pointer.
        let next_ptr = u8::try_from(next).map_err(|_| PacketError::BadPointer)?;
        let bytes = self.buffer.as_mut();
        arrival.encode(&mut bytes[ptr..])?;
        bytes[PTR_OFFSET] = next_ptr;
        Ok(next_instruction)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::fmt::Write;

    fn display(e: PacketError) -> heapless::String<64> {
        let mut s = heapless::String::new();
        write!(s, "{e}").unwrap();
        s
    }

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
            Packet::new_checked(&[5, 0, 0, 0][..]).unwrap_err(),
            PacketError::Truncated
        );
        assert_eq!(
            Packet::new_checked(&[4, 0, 0, 0, 0, 0][..]).unwrap_err(),
            PacketError::BadPointer
        );
        assert_eq!(
            Packet::new_checked(&[6, 0, 0, 0, 0, 0][..]).unwrap_err(),
            PacketError::BadPointer
        );
        let p = Packet::new_checked(&[5, 0xe8, 0x03, 0x00, 0x01, 0x40, 0xC0, 0, 1][..]).unwrap();
        assert_eq!(p.ttl(), 1000);
        assert_eq!(p.mtu(), 256);
        assert_eq!(p.instruction(), Ok(Instruction::LinkForward(0)));
    }

    #[test]
    fn ingest_rewrites_the_hop_and_advances() {
        // link_forward(3) then port_handle(1 -> 2); arrives on our link 7.
        let mut pkt = [5, 0, 0, 0, 1, 0x43, 0xC0, 0x08, 0x02, 0xAA];
        let mut p = Packet::new_checked(&mut pkt[..]).unwrap();
        let next = p.ingest(Instruction::LinkForward(7)).unwrap();
        assert_eq!(next, Instruction::PortHandle { src: 1, dst: 2 });
        assert_eq!(pkt[0], 6);
        assert_eq!(pkt[5], 0x47);
    }

    #[test]
    fn ingest_refuses_a_terminal_at_ptr() {
        let mut pkt = [5, 0, 0, 0, 1, 0xC0, 0x08, 0x02];
        let mut p = Packet::new_checked(&mut pkt[..]).unwrap();
        assert_eq!(
            p.ingest(Instruction::LinkForward(0)),
            Err(PacketError::UnexpectedInstruction)
        );
        // A forward with nothing after it has no instruction to advance to.
        let mut pkt = [5, 0, 0, 0, 1, 0x41];
        let mut p = Packet::new_checked(&mut pkt[..]).unwrap();
        assert_eq!(
            p.ingest(Instruction::LinkForward(0)),
            Err(PacketError::BadPointer)
        );
        // A refused ingest leaves the packet as it was.
        assert_eq!(pkt, [5, 0, 0, 0, 1, 0x41]);
    }

    #[test]
    fn ingest_refuses_an_arrival_that_cannot_be_encoded() {
        let mut pkt = [5, 0, 0, 0, 1, 0x43, 0x01];
        let mut p = Packet::new_checked(&mut pkt[..]).unwrap();
        assert_eq!(
            p.ingest(Instruction::LinkForward(MAX_LINKS)),
            Err(PacketError::FieldOutOfRange)
        );
        assert_eq!(pkt, [5, 0, 0, 0, 1, 0x43, 0x01]);
    }

    #[test]
    fn setters_round_trip() {
        let mut p = Packet::new_checked([5u8, 0, 0, 0, 0, 0x41, 0x42, 0x01]).unwrap();
        p.set_ttl(0xBEEF);
        p.set_mtu(1500);
        p.set_ptr(6).unwrap();
        assert_eq!(p.ttl(), 0xBEEF);
        assert_eq!(p.mtu(), 1500);
        assert_eq!(p.ptr(), 6);
        assert_eq!(p.instruction(), Ok(Instruction::LinkForward(2)));
        // The wire layout: ptr, then little-endian ttl and mtu.
        assert_eq!(p.as_bytes()[..HEADER_LEN], [6, 0xEF, 0xBE, 0xDC, 0x05]);
        // A pointer into the header or past the end is refused and not set.
        assert_eq!(p.set_ptr(4), Err(PacketError::BadPointer));
        assert_eq!(p.set_ptr(8), Err(PacketError::BadPointer));
        assert_eq!(p.ptr(), 6);
        let bytes = p.into_inner();
        assert_eq!(Packet::new_checked(&bytes[..]).unwrap().walked(), &[0x41]);
    }

    #[test]
    fn checked_constructor_refuses_truncated_and_bad_pointers() {
        for len in 0..MIN_PACKET_LEN {
            let bytes = [5u8; MIN_PACKET_LEN];
            assert_eq!(
                Packet::new_checked(&bytes[..len]),
                Err(PacketError::Truncated),
                "{len} bytes"
            );
        }
        for ptr in [0u8, 1, 4, 6, 255] {
            let bytes = [ptr, 0, 0, 0, 0, 0];
            assert_eq!(
                Packet::new_checked(&bytes[..]),
                Err(PacketError::BadPointer),
                "ptr {ptr}"
            );
        }
        // An unchecked view of the same bytes checks the same way later.
        assert_eq!(
            Packet::new_unchecked(&[9u8, 0, 0, 0, 0, 0][..]).check_len(),
            Err(PacketError::BadPointer)
        );
    }

    #[test]
    fn errors_display() {
        assert_eq!(display(PacketError::Truncated), "packet is truncated");
        assert_eq!(
            display(PacketError::BadPointer),
            "instruction pointer is out of range"
        );
    }
}
