//! The simulated bed `[sim.bed]` describes, as the simulator's surface.

use osap_sim::machine::bed::BedSurface;

use crate::config::{MachineFile, SimBed};

impl SimBed {
    /// The bed as the simulator's surface: centred on the middle of the
    /// x-y travel, the dome falling to 0 at its edges. `None` without axes
    /// x and y.
    pub fn surface(&self, cfg: &MachineFile) -> Option<BedSurface> {
        let (x, y) = (cfg.axes.get("x")?, cfg.axes.get("y")?);
        Some(BedSurface {
            z: self.z,
            tilt_x: self.tilt_x,
            tilt_y: self.tilt_y,
            warp: self.warp,
            center: [(x.min + x.max) / 2.0, (y.min + y.max) / 2.0],
            half: [(x.max - x.min) / 2.0, (y.max - y.min) / 2.0],
        })
    }
}
