//! One simulated PEIS on any tuple space: its init component with simulated
//! component bodies, and faults injected by tuples.
//!
//! A fault reaches a PEIS that runs as a process of its own as its tuple
//! `C.fault`, set by remote set from anywhere (`ecology tuples set hsm
//! ca1.fault stall`): `stall` (the component falls silent), `garble` (it
//! writes its outputs in a form nobody reads), `fail CAUSE` (it reports
//! `error` with CAUSE), `recover` or an empty value (the fault is cleared).

use std::future::Future;
use std::sync::Arc;

use ecology_peis::{ComponentSpec, HostError, HostOptions, run_host_with};
use ecology_ros2::{Agent, Ros2Component, announce_topics};
use ecology_tuples::{Clock, TupleError, TupleEvent, TuplePattern, TupleSpace};

use crate::components::{FaultState, Faults, Simulated};
use crate::scenario::PeisDef;

/// The component specs of PEIS `def`, with simulated bodies sharing `faults`; its ROS 2 nodes
/// are left out.
pub fn simulated_components<S: TupleSpace>(
    def: &PeisDef,
    faults: &Faults,
    seed: u64,
) -> Vec<ComponentSpec<S>> {
    def.components
        .iter()
        .filter(|c| c.ros2.is_none())
        .filter_map(|c| {
            let body = Simulated::new(&c.kind, faults.clone(), seed)?.covering(&c.covers);
            Some(ComponentSpec {
                name: c.id.clone(),
                kind: c.kind.clone(),
                cost: c.cost,
                on: c.on,
                startup: c.startup,
                covers: c.covers.clone(),
                body: Arc::new(body),
            })
        })
        .collect()
}

/// A fault as written in a `C.fault` tuple; `None` when the text is none of them.
pub fn parse_fault(text: &str) -> Option<FaultState> {
    let text = text.trim();
    let (word, rest) = text.split_once(char::is_whitespace).unwrap_or((text, ""));
    match word {
        "" | "recover" => Some(FaultState::default()),
        "stall" => Some(FaultState {
            stalled: true,
            ..FaultState::default()
        }),
        "garble" => Some(FaultState {
            garbled: true,
            ..FaultState::default()
        }),
        "fail" => Some(FaultState {
            failed: Some(match rest.trim() {
                "" => "injected failure".to_string(),
                cause => cause.to_string(),
            }),
            ..FaultState::default()
        }),
        _ => None,
    }
}

/// The component specs of PEIS `def`'s ROS 2 nodes, each driven through `agent`.
pub fn ros2_components<S: TupleSpace>(def: &PeisDef, agent: &Agent) -> Vec<ComponentSpec<S>> {
    def.components
        .iter()
        .filter_map(|c| {
            let spec = c.ros2.clone()?;
            let body = Ros2Component::new(agent.clone(), format!("{}:{}", def.name, c.id), spec);
            Some(ComponentSpec {
                name: c.id.clone(),
                kind: c.kind.clone(),
                cost: c.cost,
                on: c.on,
                startup: c.startup,
                covers: c.covers.clone(),
                body: Arc::new(body),
            })
        })
        .collect()
}

/// Runs PEIS `def` on `space` (which acts as that PEIS) with simulated
/// components, and its ROS 2 nodes through `agent` (needed when it has any),
/// until `shutdown` completes, applying `C.fault` tuples as they
/// are set and telling `note` about each (`ca1 stalls`), and about what the
/// host puts back by itself when the PEIS that asked for it is gone.
pub async fn host_peis<S: TupleSpace>(
    space: S,
    clock: Arc<dyn Clock>,
    def: &PeisDef,
    seed: u64,
    agent: Option<&Agent>,
    note: impl Fn(String) + Send + Sync + 'static,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), HostError> {
    let note: Arc<dyn Fn(String) + Send + Sync> = Arc::new(note);
    let faults = Faults::default();
    let me = space.peis().clone();
    let pattern = TuplePattern::parse(&format!("{me}:*.fault"))
        .map_err(|e| HostError::Space(TupleError::Invalid(e)))?;
    let mut fault_tuples = space.subscribe(pattern).await?;
    let options = HostOptions {
        note: note.clone(),
        ..HostOptions::default()
    };
    let mut components = simulated_components(def, &faults, seed);
    if let Some(agent) = agent {
        components.extend(ros2_components(def, agent));
        for c in &def.components {
            if let Some(spec) = &c.ros2 {
                announce_topics(&space, &c.id, spec).await?;
            }
        }
    }
    let host = run_host_with(space, clock, components, options, shutdown);
    tokio::pin!(host);
    loop {
        tokio::select! {
            biased;
            result = &mut host => return result,
            Some(event) = fault_tuples.next() => {
                let TupleEvent::Changed(tuple) = event else { continue };
                let Some(component) = tuple.key.as_str().strip_suffix(".fault") else { continue };
                if !def.components.iter().any(|c| c.id == component) {
                    note(format!("fault for unknown component {component} ignored"));
                    continue;
                }
                let text = tuple.text().unwrap_or("");
                match parse_fault(text) {
                    Some(state) => {
                        let what = match (&state.failed, state.stalled, state.garbled) {
                            (Some(cause), _, _) => format!("{component} fails: {cause}"),
                            (None, true, _) => format!("{component} stalls (stops publishing)"),
                            (None, false, true) => {
                                format!("{component} garbles its outputs")
                            }
                            (None, false, false) => format!("{component} recovers"),
                        };
                        faults.update(me.as_str(), component, |s| *s = state);
                        note(what);
                    }
                    None => note(format!(
                        "fault `{text}` for {component} ignored (known: stall, garble, fail CAUSE, recover)"
                    )),
                }
            }
        }
    }
}
