//! Any module function, called by the module's key in `[modules]`.

use super::*;
use crate::network::modfn::ModuleCall;

pub(super) fn som_refusal(module: &str, function: &str, e: SomError) -> MachineError {
    match e {
        SomError::Remote {
            error: ControlError::CallFailed(code),
            failure,
            ..
        } => MachineError::ModuleRefused {
            module: module.into(),
            function: function.into(),
            reason: failure.map_or_else(
                || format!("failure code {}", code.code()),
                |f| f.to_string(),
            ),
        },
        other => MachineError::Network(other),
    }
}

impl Machine {
    /// Calls function `function` on module `key` (of `[modules]`).
    pub async fn call(
        &self,
        key: &str,
        function: &str,
        args: &[Value<'static>],
    ) -> Result<Vec<Value<'static>>, MachineError> {
        self.call_as(key, function, args, false).await
    }

    /// Calls module function `C` on module `key` with `inputs` (typed:
    /// its name and arguments come from the module's own table).
    pub(super) async fn call_module<C: ModuleCall>(
        &self,
        key: &str,
        inputs: C,
    ) -> Result<Vec<Value<'static>>, MachineError> {
        self.call_as(key, C::NAME, &inputs.values(), false).await
    }

    /// [`call_module`](Self::call_module) for a function that sets or
    /// reads a value, asked again if its reply is lost (a noisy link must
    /// not fail a recovery).
    pub(super) async fn call_idempotent<C: ModuleCall>(
        &self,
        key: &str,
        inputs: C,
    ) -> Result<Vec<Value<'static>>, MachineError> {
        self.call_as(key, C::NAME, &inputs.values(), true).await
    }

    pub(super) async fn call_as(
        &self,
        key: &str,
        function: &str,
        args: &[Value<'static>],
        idempotent: bool,
    ) -> Result<Vec<Value<'static>>, MachineError> {
        let runtime = &self
            .inner
            .modules
            .get(key)
            .ok_or_else(|| MachineError::ModuleNotFound {
                key: key.into(),
                wanted: key.into(),
                found: self
                    .inner
                    .modules
                    .keys()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", "),
            })?
            .runtime;
        let h = self
            .inner
            .manager
            .lock()
            .await
            .function(&FnRef::new(runtime.as_str(), function))?;
        let result = if idempotent {
            h.call_idempotent(args).await
        } else {
            h.call(args).await
        };
        result.map_err(|e| som_refusal(key, function, e))
    }
}
