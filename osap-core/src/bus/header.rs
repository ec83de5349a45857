//! The bus frame header: link-layer addressing on a multi-drop medium.
//!
//! Every frame on a bus starts with three bytes ahead of the OSAP packet
//! (and inside the byte-stream framing, so the frame's CRC covers them):
//!
//! ```text
//! byte 0  dst    drop the frame is for (0 = head, 1..=254 drops, 255 = all)
//! byte 1  src    drop that sent it (0..=254; 255 is never a sender)
//! byte 2  flags  bit 0 GRANT: the head gives the medium to `dst`
//!                bit 1 END:   the sender hands the medium back to the head
//!                bits 3..2 TURN: the grant's turn number (0..=3), set by the
//!                             head on a grant and echoed by the drop on
//!                             every frame of that turn
//!                bits 7..4 reserved, zero
//! ```
//!
//! The turn number lets the head tell a drop's answer to the current grant
//! from a late frame of an earlier one (which must not end the current
//! turn).
//!
//! A frame may carry no packet at all (a bare grant or end).

/// Bytes the bus header takes ahead of the packet.
pub const HEADER_LEN: usize = 3;
/// The head's drop address.
pub const HEAD: u8 = 0;
/// The destination that addresses every drop.
pub const BROADCAST: u8 = 255;
/// Flag: the head grants the medium to `dst`.
pub const GRANT: u8 = 0x01;
/// Flag: the sender returns the medium to the head.
pub const END: u8 = 0x02;
/// Flag bits holding the turn number.
pub const TURN_MASK: u8 = 0x0C;
const TURN_SHIFT: u32 = 2;
const KNOWN_FLAGS: u8 = GRANT | END | TURN_MASK;

/// A parsed bus frame header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusHeader {
    /// Destination drop (or [`BROADCAST`]).
    pub dst: u8,
    /// Sending drop.
    pub src: u8,
    /// [`GRANT`] and [`END`] bits and the turn number ([`TURN_MASK`]).
    pub flags: u8,
}

/// The flag bits carrying turn number `turn` (taken mod 4).
pub const fn turn_flags(turn: u8) -> u8 {
    (turn << TURN_SHIFT) & TURN_MASK
}

/// Why a bus frame was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum BusFrameError {
    /// Shorter than the header.
    Truncated,
    /// The source is the broadcast address.
    BadSource,
    /// A reserved flag bit is set, or a grant does not come from the head
    /// or is broadcast.
    BadFlags,
}

impl core::fmt::Display for BusFrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            BusFrameError::Truncated => "bus frame shorter than its header",
            BusFrameError::BadSource => "bus frame from the broadcast address",
            BusFrameError::BadFlags => "bus frame with invalid flags",
        })
    }
}

impl core::error::Error for BusFrameError {}

impl BusHeader {
    /// Splits `frame` into its header and the packet after it.
    pub fn parse(frame: &[u8]) -> Result<(BusHeader, &[u8]), BusFrameError> {
        let (&[dst, src, flags], packet) = frame
            .split_first_chunk::<HEADER_LEN>()
            .ok_or(BusFrameError::Truncated)?;
        if src == BROADCAST {
            return Err(BusFrameError::BadSource);
        }
        if flags & !KNOWN_FLAGS != 0 {
            return Err(BusFrameError::BadFlags);
        }
        // Only the head grants, and only to one drop at a time.
        if flags & GRANT != 0 && (src != HEAD || dst == BROADCAST || dst == HEAD) {
            return Err(BusFrameError::BadFlags);
        }
        Ok((BusHeader { dst, src, flags }, packet))
    }

    /// The turn number the frame carries.
    pub const fn turn(&self) -> u8 {
        (self.flags & TURN_MASK) >> TURN_SHIFT
    }

    /// The three header bytes.
    pub const fn to_bytes(self) -> [u8; HEADER_LEN] {
        [self.dst, self.src, self.flags]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_round_trips() {
        let h = BusHeader {
            dst: 3,
            src: 0,
            flags: GRANT,
        };
        let mut frame = [0u8; 5];
        frame[..3].copy_from_slice(&h.to_bytes());
        frame[3..].copy_from_slice(&[9, 9]);
        assert_eq!(BusHeader::parse(&frame), Ok((h, &[9u8, 9][..])));
        let (h, _) = BusHeader::parse(&[3, 0, GRANT | turn_flags(3)]).unwrap();
        assert_eq!((h.turn(), h.flags & GRANT), (3, GRANT));
        assert_eq!(turn_flags(5), turn_flags(1));
    }

    #[test]
    fn refuses_malformed_headers() {
        assert_eq!(BusHeader::parse(&[1, 2]), Err(BusFrameError::Truncated));
        assert_eq!(
            BusHeader::parse(&[1, 255, 0]),
            Err(BusFrameError::BadSource)
        );
        assert_eq!(
            BusHeader::parse(&[1, 0, 0x10]),
            Err(BusFrameError::BadFlags)
        );
        // A drop cannot grant, and nobody grants to all.
        assert_eq!(
            BusHeader::parse(&[2, 1, GRANT]),
            Err(BusFrameError::BadFlags)
        );
        assert_eq!(
            BusHeader::parse(&[255, 0, GRANT]),
            Err(BusFrameError::BadFlags)
        );
    }
}
