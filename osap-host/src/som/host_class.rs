//! PIPES classes defined by host code.
//!
//! A type with `#[pipes_core::class]` (any [`PipesClass`]) attached to a
//! [`Host`] with [`attach_class`] runs in that host's runtime exactly as it
//! would on a module: one control port of type
//! [`CLASS_PORT_TYPE`](pipes_core::class::CLASS_PORT_TYPE) named after the
//! class that answers the function protocol with the constructor signature
//! (a call rebuilds the state) and runs the loop hook on every poll, then
//! one PIPES function per exported member, named `"Class.member"`, with
//! [`HOST_FN_PIPES`] pipe slots each. Members are ordinary functions: the
//! manager lists them, [`FunctionHandle`](super::FunctionHandle)s call them
//! and pipes run to and from them.
//!
//! On a module the state lives in a `RefCell` the ports borrow. A host
//! runtime's ports must be `Send + 'static`, so here the state is an
//! `Arc<Mutex<C>>` shared by the ports and the returned [`ClassHandle`]:
//! the script can read (or change) the state between calls. Members lock it
//! only for the length of a call, inside the runtime's task; a script should
//! likewise hold the lock only briefly, and never across an `.await`, since
//! the runtime waits for it.

use super::host_fn::{HOST_FN_PIPES, HOST_FN_QUEUE, HOST_FN_STORE};
use super::SomError;
use crate::Host;
use osap_core::port::{Delivery, Port, PortInfo, PortTx};
use pipes_core::class::{PipesClass, CLASS_PORT_TYPE};
use pipes_core::export::NO_SUCH_MEMBER;
use pipes_core::function::{CallError, Implementation, Outputs, PipesFunction};
use pipes_core::signature::Signature;
use pipes_core::Value;
use std::sync::{Arc, Mutex, MutexGuard};

/// The state of a host class, shared by its ports and its handle.
pub type SharedState<C> = Arc<Mutex<C>>;

/// Locks the state; a member that panicked (and so poisoned the lock) took
/// the runtime down with it, so a poisoned lock is simply taken over.
fn lock<C>(state: &Mutex<C>) -> MutexGuard<'_, C> {
    state
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// One member over the shared state.
struct HostMember<C> {
    state: SharedState<C>,
    index: usize,
    sig: &'static Signature,
}

impl<C: PipesClass> Implementation for HostMember<C> {
    fn signature(&self) -> &'static Signature {
        self.sig
    }

    fn call(&mut self, inputs: &[Value<'_>], outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        if self.index >= C::MEMBERS.len() {
            return Err(CallError::Failed(pipes_core::FailureCode::from_code(
                NO_SUCH_MEMBER,
            )));
        }
        lock(&self.state).call_member(self.index, inputs, outputs)
    }
}

/// The constructor over the shared state: replaces it.
struct HostConstructor<C> {
    state: SharedState<C>,
}

impl<C: PipesClass> Implementation for HostConstructor<C> {
    fn signature(&self) -> &'static Signature {
        C::CONSTRUCTOR
    }

    fn call(&mut self, inputs: &[Value<'_>], _outputs: &mut Outputs<'_>) -> Result<(), CallError> {
        let new = C::construct(inputs)?;
        *lock(&self.state) = new;
        Ok(())
    }
}

/// The class's own port: the constructor as a function with no pipe slots,
/// listed as a class, running the loop hook on every poll.
struct HostClassPort<C> {
    ctor: PipesFunction<HostConstructor<C>, 0, 1, HOST_FN_STORE>,
    state: SharedState<C>,
}

impl<C: PipesClass> Port for HostClassPort<C> {
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
        lock(&self.state).loop_hook(tx.system_time());
        self.ctor.poll(tx);
    }

    fn wake_at(&self) -> Option<osap_core::Instant> {
        // The constructor's own timers (a segmented reply in progress).
        self.ctor.wake_at()
    }
}

/// A class attached to a host runtime by [`attach_class`]: its shared state
/// and where its ports are.
pub struct ClassHandle<C> {
    state: SharedState<C>,
    port: u16,
    members: Vec<(&'static str, u16)>,
}

impl<C> Clone for ClassHandle<C> {
    fn clone(&self) -> Self {
        ClassHandle {
            state: self.state.clone(),
            port: self.port,
            members: self.members.clone(),
        }
    }
}

impl<C: PipesClass> std::fmt::Debug for ClassHandle<C> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClassHandle")
            .field("class", &C::NAME)
            .field("port", &self.port)
            .field("members", &self.members)
            .finish()
    }
}

impl<C: PipesClass> ClassHandle<C> {
    /// The class name.
    pub fn name(&self) -> &'static str {
        C::NAME
    }

    /// The state the members run on (hold the lock briefly: see the module
    /// docs).
    pub fn state(&self) -> &SharedState<C> {
        &self.state
    }

    /// The class port's index in its runtime.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Every member's function name (`"Class.member"`) and control port,
    /// in [`PipesClass::MEMBERS`] order.
    pub fn members(&self) -> &[(&'static str, u16)] {
        &self.members
    }

    /// The function name of the member whose Rust name is `member` (without
    /// the class prefix), e.g. `"Comparator.feed"` for `"feed"`.
    pub fn member(&self, member: &str) -> Option<&'static str> {
        C::member_index(member).and_then(|i| self.members.get(i).map(|m| m.0))
    }

    /// The control port of the member whose Rust name is `member`.
    pub fn member_port(&self, member: &str) -> Option<u16> {
        C::member_index(member).and_then(|i| self.members.get(i).map(|m| m.1))
    }
}

/// Attaches an instance of class `C`, starting from `state`, to `host`'s
/// runtime: the class port, then one PIPES function per member (each a
/// control port followed by [`HOST_FN_PIPES`] pipe ports). Returns the
/// handle to its state and ports. Refused (before anything is attached) if
/// a signature is beyond the limits of a function.
pub async fn attach_class<C>(host: &Host, state: C) -> Result<ClassHandle<C>, SomError>
where
    C: PipesClass + Send + 'static,
{
    let bad = |name: &str, e: pipes_core::signature::SignatureError| SomError::BadDefinition {
        name: name.to_string(),
        detail: e.to_string(),
    };
    let state: SharedState<C> = Arc::new(Mutex::new(state));
    let class_port = HostClassPort {
        ctor: PipesFunction::new(HostConstructor {
            state: state.clone(),
        })
        .map_err(|e| bad(C::NAME, e))?,
        state: state.clone(),
    };
    let mut members = Vec::with_capacity(C::MEMBERS.len());
    for (index, &sig) in C::MEMBERS.iter().enumerate() {
        let f: PipesFunction<HostMember<C>, HOST_FN_PIPES, HOST_FN_QUEUE, HOST_FN_STORE> =
            PipesFunction::new(HostMember {
                state: state.clone(),
                index,
                sig,
            })
            .map_err(|e| bad(sig.name, e))?;
        members.push((sig.name, f));
    }
    let port = host.attach_port(Box::new(class_port)).await?;
    let mut attached = Vec::with_capacity(members.len());
    for (name, f) in members {
        attached.push((name, host.attach_port(Box::new(f)).await?));
    }
    Ok(ClassHandle {
        state,
        port,
        members: attached,
    })
}
