//! A probe port: sends what it is given, records what it receives, and can
//! echo. For tests and for generating traffic in a simulation.

use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::route::Route;
use osap_core::Instant;
use std::collections::VecDeque;

/// A packet a [`ProbePort`] received.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProbeDelivery {
    /// Payload, transport key included.
    pub payload: Vec<u8>,
    /// Route back to the sender.
    pub reply_route: Route,
    /// The sending port.
    pub source_port: u16,
    /// Arrival time in the receiving runtime (the link's receive stamp when
    /// it gave one), local µs.
    pub arrival: Instant,
    /// Local time of the poll that delivered it, µs.
    pub delivered_at: Instant,
}

/// A send waiting for the probe's next poll.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProbeSend {
    /// Route to the destination runtime.
    pub route: Route,
    /// Destination port.
    pub dst: u16,
    /// Time to live, µs.
    pub ttl: u16,
    /// Payload, transport key included.
    pub payload: Vec<u8>,
}

/// A port that sends queued packets when polled and records deliveries.
#[derive(Debug, Clone, Default)]
pub struct ProbePort {
    /// Everything received, oldest first.
    pub received: Vec<ProbeDelivery>,
    /// Sends waiting for the next poll.
    pub outbox: VecDeque<ProbeSend>,
    /// Local times at which queued packets were handed to the runtime.
    pub sent_at: Vec<Instant>,
    /// Reply to every packet with its own payload.
    pub echo: bool,
    /// Sends the runtime refused.
    pub send_errors: usize,
}

impl ProbePort {
    /// A probe that echoes what it receives.
    pub fn echo() -> Self {
        ProbePort {
            echo: true,
            ..ProbePort::default()
        }
    }

    /// Queues a send for the next poll.
    pub fn queue(&mut self, route: Route, dst: u16, ttl: u16, payload: &[u8]) {
        self.outbox.push_back(ProbeSend {
            route,
            dst,
            ttl,
            payload: payload.to_vec(),
        });
    }
}

impl Port for ProbePort {
    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: "probe",
            name: if self.echo { "echo" } else { "" },
        }
    }

    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        if self.echo
            && tx
                .send(&d.reply_route, d.source_port, 10_000, d.payload)
                .is_err()
        {
            self.send_errors += 1;
        }
        self.received.push(ProbeDelivery {
            payload: d.payload.to_vec(),
            reply_route: d.reply_route,
            source_port: d.source_port,
            arrival: d.arrival,
            delivered_at: tx.now(),
        });
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        while tx.clear_to_send() {
            let Some(s) = self.outbox.pop_front() else {
                break;
            };
            match tx.send(&s.route, s.dst, s.ttl, &s.payload) {
                Ok(()) => self.sent_at.push(tx.now()),
                Err(_) => self.send_errors += 1,
            }
        }
    }
}
