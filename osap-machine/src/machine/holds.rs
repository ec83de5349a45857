//! Who asks a module function to run on its timer: the machine's own
//! reports and any recorders share one input mode per function.

use std::collections::BTreeMap;
use std::sync::Mutex;

use osap_host::som::FnRef;
use pipes_core::control::InputMode;

/// Who asks a module function to run on its timer, and how often: the
/// machine's own reports and any number of recorders share one input
/// mode per function, the fastest timer.
#[derive(Debug, Default)]
pub(crate) struct Holds {
    by_function: Mutex<BTreeMap<(String, String), HoldSet>>,
}

#[derive(Debug)]
struct HoldSet {
    /// What the machine itself wants.
    base: InputMode,
    /// Recorders: id and period.
    holders: Vec<(u32, u32)>,
}

impl HoldSet {
    fn effective(&self) -> InputMode {
        let held = self.holders.iter().map(|h| h.1).min();
        match (self.base, held) {
            (InputMode::OnTimer(b), Some(h)) => InputMode::OnTimer(b.min(h)),
            (_, Some(h)) => InputMode::OnTimer(h),
            (b, None) => b,
        }
    }
}

fn key(f: &FnRef) -> (String, String) {
    (f.runtime.clone(), f.function.clone())
}

#[cfg_attr(not(feature = "capture"), allow(dead_code))]
impl Holds {
    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<(String, String), HoldSet>> {
        self.by_function.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// A recorder `id` wants `f` run every `period_us`; `current` is its
    /// mode now. Returns the mode to set.
    pub(crate) fn acquire(
        &self,
        f: &FnRef,
        id: u32,
        period_us: u32,
        current: InputMode,
    ) -> InputMode {
        let mut map = self.lock();
        let set = map.entry(key(f)).or_insert(HoldSet {
            base: current,
            holders: Vec::new(),
        });
        set.holders.push((id, period_us));
        set.effective()
    }

    /// Recorder `id` is done with `f`. Returns the mode to set.
    pub(crate) fn release(&self, f: &FnRef, id: u32) -> Option<InputMode> {
        let mut map = self.lock();
        let set = map.get_mut(&key(f))?;
        set.holders.retain(|h| h.0 != id);
        let mode = set.effective();
        if set.holders.is_empty() {
            map.remove(&key(f));
        }
        Some(mode)
    }

    /// The machine wants `f` in `mode`: the mode to set, faster if a
    /// recorder holds it.
    pub(crate) fn machine_sets(&self, f: &FnRef, mode: InputMode) -> InputMode {
        match self.lock().get_mut(&key(f)) {
            Some(set) => {
                set.base = mode;
                set.effective()
            }
            None => mode,
        }
    }
}
