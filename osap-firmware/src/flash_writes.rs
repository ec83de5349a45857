//! Flash writes the network asks for (a new name, a UART bus role), held
//! until the axis stands.
//!
//! Erasing a flash sector stalls the program for tens of milliseconds (an
//! RP2040 runs with execute-in-place off for the whole write, about 45 ms
//! for an erase), far longer than the step generator's FIFO lasts (8 words,
//! 1.28 ms): a write while motion is queued would make steps late, or lose
//! them. So, as the clock rate's save waits ([`crate::hot_start`]), a name
//! or bus role the network sets takes effect at once (the runtime answers
//! with it, the link switches its role) but reaches the flash only once the
//! axis stands: no stream queued or running, no step owed, or the motor
//! disabled or halted (`osap_module::stepper::Stepper::is_standing`).
//! Several changes while moving make one write each of the latest name and
//! role.
//!
//! A write that starts while the axis stands still stalls the runtime's
//! loop: points that arrive meanwhile wait in the link's buffers, so a
//! stream should be sent further ahead than a write lasts.

use crate::name_store::{Name, NameFlash, NameStore, StoreError};
use osap_core::bus::BusRole;

/// The writes waiting for the axis to stand.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PendingWrites {
    /// The latest name set, not yet written.
    name: Option<Name>,
    /// The latest bus role taken, not yet written.
    bus: Option<BusRole>,
}

/// What [`PendingWrites::write_due`] wrote: per record, `None` if nothing
/// was due, else the store's answer (`Ok(false)`: already stored).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Written<E> {
    /// The name record.
    pub name: Option<Result<bool, StoreError<E>>>,
    /// The bus role record.
    pub bus: Option<Result<bool, StoreError<E>>>,
}

impl PendingWrites {
    /// Nothing waiting.
    pub const fn new() -> Self {
        PendingWrites {
            name: None,
            bus: None,
        }
    }

    /// The network set the runtime's name to `name`: write it once the
    /// axis stands. A name too long for a record is dropped (the runtime
    /// never takes one).
    pub fn name_changed(&mut self, name: &str) {
        self.name = Name::try_from(name).ok();
    }

    /// A link took bus role `role`: write it once the axis stands.
    pub fn bus_changed(&mut self, role: BusRole) {
        self.bus = Some(role);
    }

    /// Whether nothing is waiting.
    pub fn is_empty(&self) -> bool {
        self.name.is_none() && self.bus.is_none()
    }

    /// Writes what is waiting to `names` if the axis stands (`standing`);
    /// while it moves, writes nothing and keeps it all. A failed write is
    /// not retried (the runtime logs it; the value stays in force until
    /// the next boot).
    pub fn write_due<F: NameFlash>(
        &mut self,
        standing: bool,
        names: &mut NameStore<F>,
    ) -> Written<F::Error> {
        if !standing {
            return Written {
                name: None,
                bus: None,
            };
        }
        Written {
            name: self.name.take().map(|n| names.save(n.as_str())),
            bus: self.bus.take().map(|role| names.save_bus(role)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sector in memory that counts its erases.
    struct Ram {
        bytes: [u8; 64],
        erases: u32,
    }

    impl NameFlash for &mut Ram {
        type Error = ();
        fn read(&mut self, buf: &mut [u8]) -> Result<(), ()> {
            buf.copy_from_slice(&self.bytes[..buf.len()]);
            Ok(())
        }
        fn erase_and_write(&mut self, record: &[u8]) -> Result<(), ()> {
            self.bytes = [0xFF; 64];
            self.bytes[..record.len()].copy_from_slice(record);
            self.erases += 1;
            Ok(())
        }
    }

    fn ram() -> Ram {
        Ram {
            bytes: [0xFF; 64],
            erases: 0,
        }
    }

    #[test]
    fn nothing_is_written_while_the_axis_moves() {
        let mut flash = ram();
        let mut pending = PendingWrites::new();
        pending.name_changed("y-axis");
        pending.bus_changed(BusRole::Drop(3));
        {
            let mut names = NameStore::new(&mut flash);
            for _ in 0..1000 {
                let w = pending.write_due(false, &mut names);
                assert_eq!((w.name, w.bus), (None, None));
            }
            assert_eq!(names.load(), None);
        }
        assert_eq!(flash.erases, 0);
        assert!(!pending.is_empty());
    }

    #[test]
    fn the_latest_values_are_written_once_it_stands() {
        let mut flash = ram();
        let mut pending = PendingWrites::new();
        // Two renames and a role while moving: one write of each, the
        // latest.
        pending.name_changed("y-axis");
        pending.bus_changed(BusRole::Drop(3));
        pending.name_changed("x-axis");
        {
            let mut names = NameStore::new(&mut flash);
            assert_eq!(pending.write_due(false, &mut names).name, None);
            let w = pending.write_due(true, &mut names);
            assert_eq!((w.name, w.bus), (Some(Ok(true)), Some(Ok(true))));
            assert!(pending.is_empty());
            assert_eq!(names.load().as_deref(), Some("x-axis"));
            assert_eq!(names.load_bus(), BusRole::Drop(3));
            // Nothing more to write.
            let w = pending.write_due(true, &mut names);
            assert_eq!((w.name, w.bus), (None, None));
            // A value already stored costs no erase.
            pending.name_changed("x-axis");
            assert_eq!(pending.write_due(true, &mut names).name, Some(Ok(false)));
        }
        assert_eq!(flash.erases, 2);
    }
}
