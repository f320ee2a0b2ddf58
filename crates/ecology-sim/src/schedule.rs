//! Random fault schedules: for testing the executive against many faults it
//! was not written for, reproducibly from a seed (`ecology run SCENARIO
//! --random-faults --seed N` replays one; `ecology sweep` runs thousands).

use std::time::Duration;

use crate::scenario::{FaultKind, FaultSpec, Scenario, Trigger};
use ecology_core::Rng;

/// How long a schedule's faults are spread over, from the start.
const SPREAD: Duration = Duration::from_secs(30);

/// `scenario` with its faults replaced by a random schedule from `seed`: one
/// to four of component failures, stalls and recoveries, PEIS crashes (most
/// of them revived a few seconds later), components slow to start (longer,
/// sometimes, than the executive's deploy timeout), and status tuples
/// delivered twice or late. The time limit grows to twenty action timeouts,
/// so that a run that hits it is stuck, not slow.
pub fn with_random_faults(scenario: &Scenario, seed: u64) -> Scenario {
    let mut scenario = scenario.clone();
    let mut rng = Rng::derive(seed, "faults");
    let components: Vec<(String, String)> = scenario
        .peis
        .iter()
        .flat_map(|p| p.components.iter().map(|c| (p.name.clone(), c.id.clone())))
        .collect();
    let mut faults = Vec::new();
    if !components.is_empty() {
        for _ in 0..1 + rng.below(4) {
            let index = usize::try_from(rng.below(components.len() as u64)).unwrap_or(0);
            let (peis, component) = components[index].clone();
            let at = Duration::from_millis(rng.below(SPREAD.as_millis() as u64));
            let fault = |kind: FaultKind, at: Duration| FaultSpec {
                kind,
                component: (!matches!(kind, FaultKind::Kill | FaultKind::Revive))
                    .then(|| component.clone()),
                peis: peis.clone(),
                trigger: Trigger::At(at),
                cause: format!("random fault of seed {seed}"),
            };
            match rng.below(8) {
                0 | 1 => faults.push(fault(FaultKind::Fail, at)),
                2 => faults.push(fault(FaultKind::Stall, at)),
                3 => faults.push(fault(FaultKind::Recover, at)),
                4 => {
                    faults.push(fault(FaultKind::Kill, at));
                    if rng.below(10) < 7 {
                        let later = at + Duration::from_millis(1_000 + rng.below(9_000));
                        faults.push(fault(FaultKind::Revive, later));
                    }
                }
                5 => faults.push(fault(FaultKind::Duplicate, at)),
                6 => faults.push(fault(FaultKind::Late, at)),
                _ => {
                    let slow = Duration::from_millis(2_000 + rng.below(13_000));
                    if let Some(def) = scenario
                        .peis
                        .iter_mut()
                        .find(|p| p.name == peis)
                        .and_then(|p| p.components.iter_mut().find(|c| c.id == component))
                    {
                        def.startup = slow;
                    }
                }
            }
        }
    }
    scenario.faults = faults;
    scenario.time_limit = scenario.time_limit.max(scenario.action_timeout * 20);
    scenario
}
