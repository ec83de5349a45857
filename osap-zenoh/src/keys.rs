//! The key expressions a bridge serves, under `osap/NAME/…`. Clients in
//! other languages are written against these names: they do not change.

/// The characters zenoh gives a meaning in key expressions, which a
/// machine's or a module's name may not carry into one.
const SPECIAL: [char; 5] = ['/', '*', '$', '?', '#'];

/// `name` as one chunk of a key expression: each of zenoh's special
/// characters (`/ * $ ? #`) replaced by `_`, and an empty name as `_`.
pub fn chunk(name: &str) -> String {
    if name.is_empty() {
        return "_".into();
    }
    name.chars()
        .map(|c| if SPECIAL.contains(&c) { '_' } else { c })
        .collect()
}

/// Every machine's info: what `osap fleet` asks.
pub const ALL_INFO: &str = "osap/*/info";

/// The keys of one machine, `osap/NAME/…`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MachineKeys {
    base: String,
}

impl MachineKeys {
    /// The keys of the machine named `name` (made a chunk by [`chunk`]).
    pub fn new(name: &str) -> MachineKeys {
        MachineKeys {
            base: format!("osap/{}", chunk(name)),
        }
    }

    /// The machine's name as its keys spell it.
    pub fn name(&self) -> &str {
        &self.base["osap/".len()..]
    }

    /// `osap/NAME/info`: queryable, the machine's description.
    pub fn info(&self) -> String {
        format!("{}/info", self.base)
    }

    /// `osap/NAME/state`: published, the machine's state and position.
    pub fn state(&self) -> String {
        format!("{}/state", self.base)
    }

    /// `osap/NAME/events`: published, one message per machine event.
    pub fn events(&self) -> String {
        format!("{}/events", self.base)
    }

    /// `osap/NAME/call/MODULE/FUNCTION`: queryable, one function call.
    pub fn call(&self, module: &str, function: &str) -> String {
        format!("{}/call/{}/{}", self.base, chunk(module), chunk(function))
    }

    /// `osap/NAME/call/*/*`: every call, as the bridge declares it.
    pub fn calls(&self) -> String {
        format!("{}/call/*/*", self.base)
    }

    /// The module and function of a call's key, if it is one of this
    /// machine's.
    pub fn parse_call<'k>(&self, key: &'k str) -> Option<(&'k str, &'k str)> {
        let rest = key.strip_prefix(&self.base)?.strip_prefix("/call/")?;
        let (module, function) = rest.split_once('/')?;
        (!module.is_empty() && !function.is_empty() && !function.contains('/'))
            .then_some((module, function))
    }

    /// `osap/NAME/home`: queryable, homes the machine.
    pub fn home(&self) -> String {
        format!("{}/home", self.base)
    }

    /// `osap/NAME/halt`: queryable, halts the machine.
    pub fn halt(&self) -> String {
        format!("{}/halt", self.base)
    }

    /// `osap/NAME/job`: queryable, runs a G-code or SVG job.
    pub fn job(&self) -> String {
        format!("{}/job", self.base)
    }

    /// `osap/NAME/capture/SOURCE`: published samples of one source.
    pub fn capture(&self, source: &str) -> String {
        format!("{}/capture/{}", self.base, chunk(source))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn special_characters_become_underscores() {
        assert_eq!(chunk("plotter"), "plotter");
        assert_eq!(chunk("a/b*c$d?e#f"), "a_b_c_d_e_f");
        assert_eq!(chunk(""), "_");
        assert_eq!(chunk("z.analog_read(0)"), "z.analog_read(0)");
        let k = MachineKeys::new("lab/3*");
        assert_eq!(k.name(), "lab_3_");
        assert_eq!(k.info(), "osap/lab_3_/info");
        assert_eq!(
            k.call("a", "get_position"),
            "osap/lab_3_/call/a/get_position"
        );
    }

    #[test]
    fn call_keys_parse_back() {
        let k = MachineKeys::new("plotter");
        assert_eq!(
            k.parse_call("osap/plotter/call/a/get_position"),
            Some(("a", "get_position"))
        );
        assert_eq!(k.parse_call("osap/plotter/call/a"), None);
        assert_eq!(k.parse_call("osap/plotter/call/a/b/c"), None);
        assert_eq!(k.parse_call("osap/other/call/a/b"), None);
        assert_eq!(k.parse_call("osap/plotter/home"), None);
    }
}
