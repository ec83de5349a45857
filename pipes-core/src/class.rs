//! PIPES classes: a group of functions sharing state.
//!
//! A class is a Rust type with a constructor, exported member functions and
//! an optional per-loop hook; [`macro@crate::class`] on its `impl` block
//! implements [`PipesClass`]. At run time the state lives in a
//! `core::cell::RefCell` that the class's ports borrow, so nothing is
//! allocated:
//!
//! - one [`ClassPort`] per instance: a control port of type
//!   [`CLASS_PORT_TYPE`] named after the class that answers the function
//!   protocol with the **constructor** signature (a call rebuilds the state
//!   from the constructor's arguments) and runs the loop hook on every poll;
//! - one [`PipesFunction`] per exported member, over a [`Member`] adapter
//!   that borrows the state for the length of each call. Members are
//!   ordinary PIPES functions: pipes, input and output modes all apply.
//!
//! Members whose Rust name starts with `_` are not exported. The state is
//! borrowed only inside a call or a hook, so members and the hook never see
//! each other half-way.
//!
//! ```ignore
//! let state = RefCell::new(Comparator::new(0.0, 1.0));
//! let class = ClassPort::<Comparator>::new(&state)?;
//! let reading = PipesFunction::<_, 2, 2, 64>::new(Member::by_name(&state, "reading").unwrap())?;
//! ```

use core::cell::RefCell;
use core::fmt;

use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use osap_core::{Instant, SystemInstant};

use crate::control::FailureCode;
use crate::function::{CallError, Implementation, Outputs, PipesFunction};
use crate::signature::{Signature, SignatureError};
use crate::value::Value;

/// Type name of a class's control port in a network scan.
pub const CLASS_PORT_TYPE: &str = "pipes_class";

/// A PIPES class: shared state with a constructor, members and a loop hook.
///
/// Implemented by [`macro@crate::class`]; by hand only if the macro does not
/// fit.
pub trait PipesClass: Sized {
    /// The class name (also the constructor signature's name).
    const NAME: &'static str;
    /// The constructor's signature: its inputs, no outputs.
    const CONSTRUCTOR: &'static Signature;
    /// The exported members' signatures, by member index. Each is named
    /// `"Class.member"`.
    const MEMBERS: &'static [&'static Signature];
    /// The constructor's documentation ([`crate::docs`]): its `///` doc
    /// comment. None by default.
    const CONSTRUCTOR_DOCS: &'static str = "";
    /// The exported members' documentation, by member index (a missing
    /// entry is none). None by default.
    const MEMBER_DOCS: &'static [&'static str] = &[];

    /// Builds the state from the constructor's inputs (already of their
    /// declared types).
    fn construct(inputs: &[Value<'_>]) -> Result<Self, CallError>;

    /// Runs member `index` on the state.
    fn call_member(
        &mut self,
        index: usize,
        inputs: &[Value<'_>],
        outputs: &mut Outputs<'_>,
    ) -> Result<(), CallError>;

    /// Called once per runtime loop by the [`ClassPort`] with the runtime's
    /// synchronized system time (what stamped data is keyed by); does
    /// nothing by default.
    fn loop_hook(&mut self, now: SystemInstant) {
        let _ = now;
    }

    /// The index of the member named `name` (without the class prefix).
    fn member_index(name: &str) -> Option<usize> {
        Self::MEMBERS.iter().position(|s| {
            s.name
                .strip_prefix(Self::NAME)
                .and_then(|r| r.strip_prefix('.'))
                == Some(name)
        })
    }
}

/// One exported member of a class, as an [`Implementation`] to wrap in a
/// [`PipesFunction`]. It borrows the state only while it runs.
pub struct Member<'a, C> {
    state: &'a RefCell<C>,
    index: usize,
    sig: &'static Signature,
}

impl<'a, C: PipesClass> Member<'a, C> {
    /// Member `index` of the class whose state is `state`.
    pub fn new(state: &'a RefCell<C>, index: usize) -> Option<Self> {
        let sig = C::MEMBERS.get(index).copied()?;
        Some(Member { state, index, sig })
    }

    /// The member named `name` (the Rust method name).
    pub fn by_name(state: &'a RefCell<C>, name: &str) -> Option<Self> {
        Member::new(state, C::member_index(name)?)
    }

    /// The member's index in [`PipesClass::MEMBERS`].
    pub fn index(&self) -> usize {
        self.index
    }

    /// The shared state.
    pub fn state(&self) -> &'a RefCell<C> {
        self.state
    }
}

impl<C> fmt::Debug for Member<'_, C> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Member")
            .field("name", &self.sig.name)
            .field("index", &self.index)
            .finish()
    }
}

impl<C: PipesClass> Implementation for Member<'_, C> {
    fn signature(&self) -> &'static Signature {
        self.sig
    }

    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        let mut s = self
            .state
            .try_borrow_mut()
            .map_err(|_| CallError::Failed(FailureCode::StateBusy))?;
        if self.index >= C::MEMBERS.len() {
            return Err(CallError::Failed(FailureCode::NoSuchMember));
        }
        s.call_member(self.index, inputs, outputs)
    }

    fn docs(&self) -> &'static str {
        C::MEMBER_DOCS.get(self.index).copied().unwrap_or("")
    }
}

/// A class's constructor as an [`Implementation`]: a call replaces the state
/// with a new one built from its arguments. It has no outputs.
pub struct Constructor<'a, C> {
    state: &'a RefCell<C>,
}

impl<'a, C: PipesClass> Constructor<'a, C> {
    /// The constructor of the class whose state is `state`.
    pub fn new(state: &'a RefCell<C>) -> Self {
        Constructor { state }
    }
}

impl<C> fmt::Debug for Constructor<'_, C> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Constructor").finish()
    }
}

impl<C: PipesClass> Implementation for Constructor<'_, C> {
    fn signature(&self) -> &'static Signature {
        C::CONSTRUCTOR
    }

    fn call(&mut self, inputs: &[Value<'_>], _outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        let new = C::construct(inputs)?;
        let mut s = self
            .state
            .try_borrow_mut()
            .map_err(|_| CallError::Failed(FailureCode::StateBusy))?;
        *s = new;
        Ok(())
    }

    fn docs(&self) -> &'static str {
        C::CONSTRUCTOR_DOCS
    }
}

/// A class instance's own port (see the module docs): answers the function
/// protocol with the constructor and runs the loop hook on every poll.
/// `B` is the byte size of each input store.
pub struct ClassPort<'a, C, const B: usize = 64> {
    ctor: PipesFunction<Constructor<'a, C>, 0, 1, B>,
    state: &'a RefCell<C>,
}

impl<'a, C: PipesClass, const B: usize> ClassPort<'a, C, B> {
    /// The port of the class whose state is `state`; refuses a constructor
    /// signature beyond the limits.
    pub fn new(state: &'a RefCell<C>) -> Result<Self, SignatureError> {
        Ok(ClassPort {
            ctor: PipesFunction::new(Constructor::new(state))?,
            state,
        })
    }

    /// The shared state.
    pub fn state(&self) -> &'a RefCell<C> {
        self.state
    }

    /// The constructor signature.
    pub fn constructor_signature(&self) -> &'static Signature {
        C::CONSTRUCTOR
    }

    /// The constructor as a function (its counters and last error).
    pub fn constructor(&self) -> &PipesFunction<Constructor<'a, C>, 0, 1, B> {
        &self.ctor
    }
}

impl<C, const B: usize> fmt::Debug for ClassPort<'_, C, B> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ClassPort")
            .field("ctor", &self.ctor)
            .finish()
    }
}

impl<C: PipesClass, const B: usize> Port for ClassPort<'_, C, B> {
    fn port_count(&self) -> u16 {
        1
    }

    fn info(&self, _offset: u16) -> PortInfo<'_> {
        PortInfo {
            type_name: CLASS_PORT_TYPE,
            name: C::NAME,
        }
    }

    fn on_packet(&mut self, d: Delivery<'_>, tx: &mut PortTx<'_>) {
        self.ctor.on_packet(d, tx);
    }

    fn poll(&mut self, tx: &mut PortTx<'_>) {
        if let Ok(mut s) = self.state.try_borrow_mut() {
            s.loop_hook(tx.system_time());
        }
        self.ctor.poll(tx);
    }

    fn wake_at(&self) -> Option<Instant> {
        // The constructor's own timers (a segmented reply in progress).
        self.ctor.wake_at()
    }
}
