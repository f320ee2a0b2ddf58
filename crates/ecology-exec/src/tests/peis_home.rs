//! An ecology's PEIS as real hosts (`ecology_peis::run_host`) on one
//! in-process tuple space: what the executive's tests and its benchmark run
//! against. The benchmark includes this file by path, so it uses nothing of
//! the crate it sits in.

use std::sync::Arc;
use std::time::Duration;

use ecology_domain::{EcologyState, Power};
use ecology_peis::{Component, ComponentSpec, HostError, run_host};
use ecology_tuples::{Clock, InProcessPeis, InProcessSpace, PeisId, PeisOptions};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

/// One running host per PEIS, each stopped by [`Hosts::stop`].
#[derive(Debug)]
pub struct Hosts {
    running: Vec<Host>,
}

#[derive(Debug)]
struct Host {
    peis: String,
    /// Its handle on the space, until it vanishes.
    handle: Option<InProcessPeis>,
    stop: oneshot::Sender<()>,
    task: JoinHandle<Result<(), HostError>>,
}

impl Hosts {
    /// Starts a host on `space` for every PEIS that has a component in
    /// `facts`, with its components as their `pc`, `cost` and `covers` facts say, each
    /// switching on in `startup`, running the body `bodies(P, C)` gives.
    pub fn start(
        space: &InProcessSpace,
        clock: &Arc<dyn Clock>,
        facts: &EcologyState,
        startup: Duration,
        mut bodies: impl FnMut(&str, &str) -> Arc<dyn Component<InProcessPeis>>,
    ) -> Result<Hosts, String> {
        let mut owners: Vec<String> = Vec::new();
        for f in facts.with_predicate("pc") {
            if !owners.iter().any(|p| *p == *f.args[0]) {
                owners.push(f.args[0].to_string());
            }
        }
        let mut running = Vec::new();
        for peis in owners {
            let id = PeisId::new(&peis).map_err(|e| format!("PEIS {peis}: {e}"))?;
            let handle = space
                .join(id, PeisOptions::default())
                .map_err(|e| format!("PEIS {peis}: {e}"))?;
            let mut specs = Vec::new();
            for f in facts.with_predicate("pc").filter(|f| *f.args[0] == *peis) {
                let c = f.args[2].to_string();
                let cost = facts
                    .component_cost(&peis, &c)
                    .ok_or_else(|| format!("no cost for {peis}:{c}"))?;
                let covers = facts
                    .with_predicate("covers")
                    .filter(|f| *f.args[0] == *peis && *f.args[1] == *c)
                    .map(|f| f.args[2].to_string())
                    .collect();
                specs.push(ComponentSpec {
                    body: bodies(&peis, &c),
                    name: c,
                    kind: f.args[1].to_string(),
                    cost: cost.amount,
                    on: cost.power == Power::On,
                    startup,
                    covers,
                });
            }
            let (stop, stopped) = oneshot::channel::<()>();
            let task = tokio::spawn(run_host(handle.clone(), clock.clone(), specs, async {
                let _ = stopped.await;
            }));
            running.push(Host {
                peis,
                handle: Some(handle),
                stop,
                task,
            });
        }
        Ok(Hosts { running })
    }

    /// Makes `peis` crash: it stops without a goodbye, and the others see it
    /// leave once its lease has run out.
    pub fn vanish(&mut self, peis: &str) {
        if let Some(handle) = self
            .running
            .iter_mut()
            .find(|h| h.peis == peis)
            .and_then(|h| h.handle.take())
        {
            handle.vanish();
        }
    }

    /// Stops every host; each one's outcome, by PEIS (a host that panicked
    /// says so as its error).
    pub async fn stop(self) -> Vec<(String, Result<(), String>)> {
        let mut outcomes = Vec::new();
        for host in self.running {
            let _ = host.stop.send(());
            let outcome = match host.task.await {
                Ok(result) => result.map_err(|e| e.to_string()),
                Err(e) => Err(format!("the host task failed: {e}")),
            };
            outcomes.push((host.peis, outcome));
        }
        outcomes
    }
}
