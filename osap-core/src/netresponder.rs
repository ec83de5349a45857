//! The netresponder: port 0 of every runtime, answering network scans.
//!
//! A scanner (the host's netrunner) sends sequential requests to port 0 and
//! builds its map of the network from the replies. Every request body is
//! `[key][fields]`; every reply is `[key][status][fields]`, where `status` is
//! [`Status::Ok`] or says why there are no fields. The layouts are in
//! `docs/protocol.md`.

use crate::bus::BusRole;
use crate::clock::Clock;
#[cfg(feature = "sync")]
use crate::clock::{TimeConfig, TimeConfigError};
use crate::codec::{CodecError, Reader, Writer};
use crate::counters::{Counters, LinkCounters};
use crate::link::LinkGateway;
use crate::port::Port;
use core::fmt::Write as _;
use heapless::{Deque, String};

/// Type name of port 0.
pub const PORT_TYPE_NAME: &str = "netresponder";

/// `arrival_link` of a runtime-information reply to a request from a port
/// in the same runtime.
pub const ARRIVED_LOCALLY: u8 = 255;

/// A link counts as having a neighbour if a packet came in on it within
/// this long. Generous: every clock-synchronised neighbour sends at least
/// once per `interval_us` (50 ms by default).
pub const NEIGHBOUR_HEARD: crate::time::Duration = crate::time::Duration::from_secs(2);

/// The `open` byte of a link-information reply: the link is closed.
pub const LINK_CLOSED: u8 = 0;
/// The `open` byte of a link-information reply: open, and a packet came in
/// on it within [`NEIGHBOUR_HEARD`].
pub const LINK_HEARD: u8 = 1;
/// The `open` byte of a link-information reply: open, but nothing came in
/// on it within [`NEIGHBOUR_HEARD`] (a UART cannot tell whether anything
/// is wired to it). Readers that only know open/closed take it as open.
pub const LINK_UNHEARD: u8 = 2;

/// Link information's optional trailing section: a bus link follows with
/// its drop address (`u8`) and the drops it knows present (256 bits as
/// eight `u32`, bit `d % 32` of word `d / 32`).
pub const LINK_KIND_BUS: u8 = 1;
/// Longest runtime, type, port or link name, in bytes of UTF-8.
pub const NAME_MAX: usize = 31;
/// Lines kept in the debug log ring.
pub const LOG_LINES: usize = 8;
/// Longest debug log line, in bytes; longer lines are cut.
pub const LOG_LINE_MAX: usize = 47;

/// Request keys of the netresponder. The time-controller keys (0x09, 0x0a,
/// 0x0c, 0x0d) exist only with osap-core's `sync` feature: a runtime built
/// without the controller answers them with [`Status::UnknownKey`].
pub mod key {
    /// Runtime information; carries the scan id used for loop detection.
    pub const RUNTIME_INFO: u8 = 0x01;
    /// The runtime's type name.
    pub const TYPE_NAME: u8 = 0x02;
    /// The runtime's name.
    pub const NAME: u8 = 0x03;
    /// Rename the runtime.
    pub const SET_NAME: u8 = 0x04;
    /// Information on one link gateway.
    pub const LINK_INFO: u8 = 0x05;
    /// Information on one port.
    pub const PORT_INFO: u8 = 0x06;
    /// Debug log lines newer than a sequence number.
    pub const DEBUG_MESSAGES: u8 = 0x07;
    /// Set which log levels are kept.
    pub const SET_VERBOSITY: u8 = 0x08;
    /// Read the time-controller configuration.
    pub const GET_TIME_CONFIG: u8 = 0x09;
    /// Write the time-controller configuration.
    pub const SET_TIME_CONFIG: u8 = 0x0A;
    /// Read the runtime's drop and event counters.
    pub const COUNTERS: u8 = 0x0B;
    /// Read the clock's status: tier, state, offset, rate, sample counts.
    pub const TIME_STATUS: u8 = 0x0C;
    /// Set the clock's rate correction (hot start from a persisted rate).
    pub const SET_CLOCK_RATE: u8 = 0x0D;
    /// Read one link's frame and drop counters.
    pub const LINK_COUNTERS: u8 = 0x0E;
    /// Set one link's bus role (off, head, or drop; see
    /// [`crate::bus::BusRole`]), on a link that can take one.
    pub const SET_BUS: u8 = 0x0F;
    /// Information on consecutive ports from one index, as many as fit in
    /// one reply (a scan's ports in a few requests, not one each).
    pub const PORT_LIST: u8 = 0x10;
    /// The stations one bus link has heard at least once (a drop that
    /// missed its last turn is missing from link information's present
    /// drops, not from these): so a scan asks every drop it ever heard,
    /// and one that went quiet is reported, not lost.
    pub const BUS_KNOWN: u8 = 0x11;
}

/// Outcome code in every netresponder reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Status {
    /// The request was answered; the reply's fields follow.
    Ok = 0,
    /// The request key is not one this runtime knows.
    UnknownKey = 1,
    /// The request body was truncated or had extra bytes.
    Malformed = 2,
    /// The link or port index does not exist.
    NoSuchIndex = 3,
    /// A value was out of range (a name too long, a bad configuration).
    InvalidValue = 4,
    /// Not allowed from where the request came: a clock write over a link
    /// the clock does not trust.
    Refused = 5,
}

impl Status {
    /// The status with this code, if any.
    pub fn from_u8(code: u8) -> Option<Status> {
        Some(match code {
            0 => Status::Ok,
            1 => Status::UnknownKey,
            2 => Status::Malformed,
            3 => Status::NoSuchIndex,
            4 => Status::InvalidValue,
            5 => Status::Refused,
            _ => return None,
        })
    }
}

/// How important a debug log line is; lower is more important.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[repr(u8)]
pub enum Level {
    /// Something failed.
    Error = 0,
    /// Something looks wrong.
    Warn = 1,
    /// Normal operation.
    Info = 2,
    /// Detail for debugging.
    Debug = 3,
}

/// Who a runtime is, as reported to a scan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// What firmware or program this is (shared by all modules of a kind).
    pub type_name: String<NAME_MAX>,
    /// This instance's name (settable over the network).
    pub name: String<NAME_MAX>,
    /// Version, major.minor.patch.
    pub version: [u8; 3],
    /// Which implementation and build this is.
    pub build: BuildKey,
    /// The function-set id of the functions it was built with (module
    /// firmware: `osap_module::FUNCTION_SET_ID`), 0 when it has none or
    /// does not say. A host may keep what it read of such a runtime's
    /// functions and trust it while the id (and version) stay the same.
    pub function_set: u32,
}

/// Which implementation a runtime is; reported in runtime information.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BuildKey {
    /// Not said.
    Unknown,
    /// osap-rs firmware on a microcontroller.
    RustEmbedded,
    /// osap-rs on a host operating system.
    RustHost,
    /// An osap-rs module simulated on a host.
    RustSimulated,
    /// Another implementation's key.
    Other(u8),
}

impl BuildKey {
    /// The key's byte on the wire.
    pub fn to_u8(self) -> u8 {
        match self {
            BuildKey::Unknown => 0,
            BuildKey::RustEmbedded => 1,
            BuildKey::RustHost => 2,
            BuildKey::RustSimulated => 3,
            BuildKey::Other(k) => k,
        }
    }

    /// The key for a byte from the wire.
    pub fn from_u8(k: u8) -> Self {
        match k {
            0 => BuildKey::Unknown,
            1 => BuildKey::RustEmbedded,
            2 => BuildKey::RustHost,
            3 => BuildKey::RustSimulated,
            k => BuildKey::Other(k),
        }
    }
}

/// A name longer than [`NAME_MAX`] bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NameTooLong;

impl core::fmt::Display for NameTooLong {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "name is longer than {NAME_MAX} bytes")
    }
}

impl core::error::Error for NameTooLong {}

/// Makes a bounded name from a string.
pub fn name(s: &str) -> Result<String<NAME_MAX>, NameTooLong> {
    String::try_from(s).map_err(|_| NameTooLong)
}

/// One debug log line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogLine {
    /// Sequence number, counting every line ever logged.
    pub seq: u32,
    /// Importance.
    pub level: Level,
    /// Text, cut to [`LOG_LINE_MAX`] bytes.
    pub text: String<LOG_LINE_MAX>,
}

/// The netresponder's own state.
#[derive(Debug, Clone)]
pub struct State {
    last_scan_id: u32,
    /// The scan id held before `last_scan_id`: what a repeated request
    /// (a retry whose first try arrived) is answered.
    prior_scan_id: u32,
    verbosity: Level,
    log: Deque<LogLine, LOG_LINES>,
    next_seq: u32,
    /// The latest bus role set over the network, for the owner to apply.
    bus_request: Option<(u8, BusRole)>,
}

impl State {
    /// Takes the latest bus role set over the network: (link, role).
    pub(crate) fn take_bus_request(&mut self) -> Option<(u8, BusRole)> {
        self.bus_request.take()
    }
}

impl Default for State {
    fn default() -> Self {
        State {
            last_scan_id: 0,
            prior_scan_id: 0,
            verbosity: Level::Info,
            log: Deque::new(),
            next_seq: 0,
            bus_request: None,
        }
    }
}

impl State {
    /// Appends a formatted log line if `level` is within the verbosity; the
    /// oldest line goes when the ring is full. Formatting links `core::fmt`
    /// (over 1 KiB of flash on a Cortex-M0+); [`log_parts`](Self::log_parts)
    /// does not.
    pub fn log(&mut self, level: Level, args: core::fmt::Arguments<'_>) {
        if level > self.verbosity {
            return;
        }
        let mut text = String::new();
        // A long line is cut short, not lost: the writer stops at capacity.
        let _ = Truncating(&mut text).write_fmt(args);
        self.push_line(level, text);
    }

    /// Appends a log line made of `parts`, cut at a character boundary to
    /// [`LOG_LINE_MAX`] bytes.
    pub fn log_parts(&mut self, level: Level, parts: &[&str]) {
        if level > self.verbosity {
            return;
        }
        let mut text = String::new();
        for part in parts {
            let _ = Truncating(&mut text).write_str(part);
        }
        self.push_line(level, text);
    }

    fn push_line(&mut self, level: Level, text: String<LOG_LINE_MAX>) {
        if self.log.is_full() {
            self.log.pop_front();
        }
        let _ = self.log.push_back(LogLine {
            seq: self.next_seq,
            level,
            text,
        });
        self.next_seq = self.next_seq.wrapping_add(1);
    }

    /// The kept log lines, oldest first.
    pub fn log_lines(&self) -> impl Iterator<Item = &LogLine> {
        self.log.iter()
    }

    /// Which levels are kept.
    pub fn verbosity(&self) -> Level {
        self.verbosity
    }

    /// The scan id most recently received.
    pub fn last_scan_id(&self) -> u32 {
        self.last_scan_id
    }
}

struct Truncating<'a, const N: usize>(&'a mut String<N>);

impl<const N: usize> core::fmt::Write for Truncating<'_, N> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for c in s.chars() {
            if self.0.push(c).is_err() {
                return Err(core::fmt::Error);
            }
        }
        Ok(())
    }
}

/// What the runtime changed in answering a request, for its owner to act on
/// (for example, persisting a new name to flash).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Changes {
    /// The runtime's name was set.
    pub name: bool,
    /// The time configuration was set.
    pub time_config: bool,
    /// The log verbosity was set.
    pub verbosity: bool,
    /// A link's bus role was set ([`crate::Runtime::take_bus_request`]).
    pub bus: bool,
}

impl Changes {
    /// Whether anything changed.
    pub fn any(&self) -> bool {
        self.name || self.time_config || self.verbosity || self.bus
    }
}

/// Everything a request may read or change.
pub(crate) struct Context<'a, P, L, const LINKS: usize> {
    pub now: crate::time::Instant,
    pub identity: &'a mut Identity,
    pub state: &'a mut State,
    pub clock: &'a mut Clock<LINKS>,
    pub counters: &'a Counters,
    pub link_counters: &'a [LinkCounters],
    /// Per link: the local time a packet last came in on it.
    pub link_heard: &'a [Option<crate::time::Instant>],
    /// Per link: stack slots held by packets that arrived on it.
    pub link_held: &'a [u8],
    /// The stack's slot count.
    pub slots: u16,
    pub changes: &'a mut Changes,
    pub ports: &'a [P],
    pub links: &'a [L],
    pub packet_size: u16,
    /// The link the request arrived on ([`ARRIVED_LOCALLY`] from a port here).
    pub arrival_link: u8,
}

impl<P: Port, L: LinkGateway, const LINKS: usize> Context<'_, P, L, LINKS> {
    fn port_count(&self) -> u16 {
        self.ports
            .iter()
            .fold(1u16, |n, p| n.saturating_add(p.port_count()))
    }

    fn port_info(&self, index: u16) -> Option<(&str, &str)> {
        if index == 0 {
            return Some((PORT_TYPE_NAME, ""));
        }
        let mut rest = index - 1;
        for p in self.ports {
            let c = p.port_count();
            if rest < c {
                let info = p.info(rest);
                return Some((info.type_name, info.name));
            }
            rest -= c;
        }
        None
    }
}

enum Fail {
    Status(Status),
    Codec(CodecError),
}

impl From<CodecError> for Fail {
    fn from(e: CodecError) -> Self {
        match e {
            CodecError::NoSpace => Fail::Codec(e),
            _ => Fail::Status(Status::Malformed),
        }
    }
}

/// Answers one request body into `out` as `[key][status][fields]`.
///
/// Returns an error only when `out` is too small even for a status reply.
pub(crate) fn respond<P: Port, L: LinkGateway, const LINKS: usize>(
    ctx: &mut Context<'_, P, L, LINKS>,
    request: &[u8],
    out: &mut Writer<'_>,
) -> Result<Status, CodecError> {
    let mut r = Reader::new(request);
    let Ok(key) = r.u8() else {
        return Err(CodecError::Truncated);
    };
    out.u8(key)?;
    out.u8(Status::Ok as u8)?;
    let mark = out.len();
    match answer(ctx, key, &mut r, out) {
        Ok(()) => Ok(Status::Ok),
        Err(Fail::Codec(e)) => Err(e),
        Err(Fail::Status(s)) => {
            // A bare status reply: drop any fields written before the failure.
            out.truncate(mark);
            out.patch_u8(mark - 1, s as u8)?;
            Ok(s)
        }
    }
}

fn end(r: &Reader<'_>) -> Result<(), Fail> {
    if r.is_empty() {
        Ok(())
    } else {
        Err(Fail::Status(Status::Malformed))
    }
}

fn answer<P: Port, L: LinkGateway, const LINKS: usize>(
    ctx: &mut Context<'_, P, L, LINKS>,
    key: u8,
    r: &mut Reader<'_>,
    out: &mut Writer<'_>,
) -> Result<(), Fail> {
    match key {
        key::RUNTIME_INFO => {
            let scan_id = r.u32()?;
            end(r)?;
            // A retry of the request it last answered gets the same answer:
            // that first try's reply may be the one that was lost.
            let previous = if scan_id == ctx.state.last_scan_id {
                ctx.state.prior_scan_id
            } else {
                ctx.state.prior_scan_id = ctx.state.last_scan_id;
                core::mem::replace(&mut ctx.state.last_scan_id, scan_id)
            };
            out.u32(previous)?;
            out.bytes(&ctx.identity.version)?;
            out.u8(ctx.identity.build.to_u8())?;
            out.u16(ctx.packet_size)?;
            out.u16(ctx.port_count())?;
            out.u8(ctx.links.len().min(64) as u8)?;
            out.u8(ctx.clock.tier())?;
            out.u8(ctx.arrival_link)?;
            out.u32(ctx.identity.function_set)?;
        }
        key::TYPE_NAME => {
            end(r)?;
            out.str8(&ctx.identity.type_name)?;
        }
        key::NAME => {
            end(r)?;
            out.str8(&ctx.identity.name)?;
        }
        key::SET_NAME => {
            let requested = r.str8()?;
            end(r)?;
            let new = name(requested).map_err(|_| Fail::Status(Status::InvalidValue))?;
            ctx.identity.name = new;
            ctx.changes.name = true;
            ctx.state
                .log_parts(Level::Info, &["renamed to ", requested]);
            out.str8(&ctx.identity.name)?;
        }
        key::LINK_INFO => {
            let index = r.u8()?;
            end(r)?;
            let link = ctx
                .links
                .get(index as usize)
                .filter(|_| index < 64)
                .ok_or(Fail::Status(Status::NoSuchIndex))?;
            let info = link.info();
            let heard = ctx
                .link_heard
                .get(usize::from(index))
                .copied()
                .flatten()
                .is_some_and(|t| ctx.now - t <= NEIGHBOUR_HEARD);
            let open = match (link.is_open(), heard) {
                (false, _) => LINK_CLOSED,
                (true, true) => LINK_HEARD,
                (true, false) => LINK_UNHEARD,
            };
            out.u8(index)?;
            out.u8(open)?;
            out.u16(link.mtu())?;
            out.str8(info.type_name)?;
            out.str8(info.name)?;
            // A bus link appends its address and the drops it knows; hosts
            // that predate buses ignore the trailing bytes.
            if let Some(bus) = link.bus() {
                out.u8(LINK_KIND_BUS)?;
                out.u8(bus.drop)?;
                for word in bus.present {
                    out.u32(word)?;
                }
            }
        }
        key::BUS_KNOWN => {
            let index = r.u8()?;
            end(r)?;
            // Not a link, or not a bus: no such bus link.
            let bus = ctx
                .links
                .get(usize::from(index))
                .and_then(LinkGateway::bus)
                .ok_or(Fail::Status(Status::NoSuchIndex))?;
            out.u8(index)?;
            for word in bus.known {
                out.u32(word)?;
            }
        }
        key::PORT_INFO => {
            let index = r.u16()?;
            end(r)?;
            let (type_name, name) = ctx
                .port_info(index)
                .ok_or(Fail::Status(Status::NoSuchIndex))?;
            out.u16(index)?;
            out.str8(type_name)?;
            out.str8(name)?;
        }
        key::PORT_LIST => {
            let from = r.u16()?;
            end(r)?;
            out.u16(from)?;
            let count_at = out.len();
            out.u8(0)?;
            let mut count = 0u8;
            // As many whole records as fit; the caller asks again from
            // `from + count` (a record too long for any reply: PORT_INFO).
            while let Some((type_name, name)) = from
                .checked_add(u16::from(count))
                .filter(|_| count < u8::MAX)
                .and_then(|i| ctx.port_info(i))
            {
                if out.remaining() < 2 + type_name.len() + name.len() {
                    break;
                }
                out.str8(type_name)?;
                out.str8(name)?;
                count += 1;
            }
            out.patch_u8(count_at, count)?;
        }
        key::DEBUG_MESSAGES => {
            let since = r.u32()?;
            end(r)?;
            out.u32(ctx.state.next_seq)?;
            let count_at = out.len();
            out.u8(0)?;
            let mut count = 0u8;
            // Send as many lines as fit; the caller asks again from the
            // last sequence number it got.
            for line in ctx.state.log.iter().filter(|l| l.seq >= since) {
                if out.remaining() < 4 + 1 + 1 + line.text.len() {
                    break;
                }
                out.u32(line.seq)?;
                out.u8(line.level as u8)?;
                out.str8(&line.text)?;
                count += 1;
            }
            out.patch_u8(count_at, count)?;
        }
        key::SET_VERBOSITY => {
            let level = r.u8()?;
            end(r)?;
            ctx.state.verbosity = match level {
                0 => Level::Error,
                1 => Level::Warn,
                2 => Level::Info,
                3 => Level::Debug,
                _ => return Err(Fail::Status(Status::InvalidValue)),
            };
            ctx.changes.verbosity = true;
            out.u8(level)?;
        }
        #[cfg(feature = "sync")]
        key::GET_TIME_CONFIG => {
            end(r)?;
            ctx.clock.config().encode(out)?;
        }
        #[cfg(feature = "sync")]
        key::SET_TIME_CONFIG => {
            let config = TimeConfig::decode(r.rest()).map_err(|e| match e {
                TimeConfigError::Codec(_) => Fail::Status(Status::Malformed),
                _ => Fail::Status(Status::InvalidValue),
            })?;
            // Who may demote, promote or retune this clock is local policy.
            if !ctx.clock.admits_write_from(ctx.arrival_link) {
                return Err(Fail::Status(Status::Refused));
            }
            ctx.clock
                .set_config(config)
                .map_err(|_| Fail::Status(Status::InvalidValue))?;
            ctx.changes.time_config = true;
            ctx.clock.config().encode(out)?;
        }
        key::COUNTERS => {
            end(r)?;
            let c = ctx.counters;
            for v in [
                c.received,
                c.forwarded,
                c.delivered,
                c.system,
                c.expired,
                c.no_route,
                c.link_closed,
                c.no_port,
                c.malformed,
                c.oversize,
                c.quota_refused,
                c.stack_full,
                c.link_errors,
                c.netresponder_errors,
                c.unknown_system,
            ] {
                out.u32(v)?;
            }
        }
        key::LINK_COUNTERS => {
            let index = r.u8()?;
            end(r)?;
            let i = usize::from(index);
            let link = ctx
                .links
                .get(i)
                .filter(|_| index < 64)
                .ok_or(Fail::Status(Status::NoSuchIndex))?;
            let mut counters = ctx.link_counters.get(i).copied().unwrap_or_default();
            counters.gateway = link.counters();
            // Packet bytes per second the link carries, from its wire time
            // for 1 KiB (0: it cannot tell).
            let us = link.transmit_time(1024).as_micros();
            counters.capacity_bytes_per_s = (1024u64 * 1_000_000)
                .checked_div(us)
                .map_or(0, |b| b.min(u64::from(u32::MAX)) as u32);
            counters.held = ctx.link_held.get(i).copied().map_or(0, u16::from);
            counters.slots = ctx.slots;
            out.u8(index)?;
            counters.encode(out)?;
        }
        #[cfg(feature = "sync")]
        key::TIME_STATUS => {
            end(r)?;
            ctx.clock.status().encode(out)?;
        }
        #[cfg(feature = "sync")]
        key::SET_CLOCK_RATE => {
            let ppb = r.u32()? as i32;
            end(r)?;
            if !ctx.clock.admits_write_from(ctx.arrival_link) {
                return Err(Fail::Status(Status::Refused));
            }
            ctx.clock.set_rate_ppb(ctx.now, ppb);
            ctx.changes.time_config = true;
            out.u32(ctx.clock.rate_ppb() as u32)?;
        }
        key::SET_BUS => {
            let index = r.u8()?;
            let bytes = [r.u8()?, r.u8()?];
            end(r)?;
            let link = ctx
                .links
                .get(usize::from(index))
                .filter(|_| index < 64)
                .ok_or(Fail::Status(Status::NoSuchIndex))?;
            let role =
                BusRole::from_bytes(bytes).map_err(|_| Fail::Status(Status::InvalidValue))?;
            if !link.bus_configurable() {
                return Err(Fail::Status(Status::Refused));
            }
            ctx.state.bus_request = Some((index, role));
            ctx.changes.bus = true;
            ctx.state.log_parts(Level::Info, &["bus role set"]);
            out.u8(index)?;
            out.bytes(&role.to_bytes())?;
        }
        _ => return Err(Fail::Status(Status::UnknownKey)),
    }
    Ok(())
}

#[cfg(test)]
mod tests;
