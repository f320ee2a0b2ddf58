//! State acquisition: a mirror of the tuples the executive subscribes to, and
//! the ecology state (the paper's Section IV) built from it.
//!
//! Each PEIS's init component publishes `components.C.type`, `.cost` and
//! `.currState`; each component publishes `C.status` and `C.cause` (DESIGN
//! section 6). Updates carry the tuple's version, `(epoch, seq)`: the epoch
//! names one run of the owner and the sequence number counts per key within
//! it. An update whose version is not newer than the last one seen is a
//! duplicate, arrived out of order, or comes from an earlier run, and is
//! dropped. An update from a later run means the PEIS restarted: what was
//! known of its components is forgotten, since the new run starts afresh.

use std::collections::{BTreeMap, BTreeSet};

use ecology_domain::{EcologyState, Fact, Name};
use ecology_tuples::contract::ComponentField;
use ecology_tuples::{ComponentId, Key, PeisId};
use rustc_hash::FxHashMap;

/// What the mirror knows of one component.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ComponentView {
    /// `components.C.type`
    pub ty: Option<String>,
    /// `components.C.cost`
    pub cost: Option<u64>,
    /// `components.C.currState` is `on`.
    pub on: bool,
    /// `C.status`
    pub status: Option<String>,
    /// `C.cause`
    pub cause: Option<String>,
    /// `C.params`, as applied by the PEIS.
    pub params: Option<String>,
    /// `components.C.holders`: the executives that hold it (claims), in the order they claimed it.
    pub holders: Vec<PeisId>,
    /// `components.C.covers`: the places it sees, as it said them (empty: it did not say).
    pub covers: Vec<String>,
}

/// What the mirror knows of one PEIS.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PeisView {
    /// Whether it is present (joined, or publishing, and not left since).
    pub present: bool,
    /// The run of the PEIS whose tuples the mirror holds (0: unknown).
    pub epoch: u64,
    /// The run that was current when it last left: its late tuples do not make it present again.
    left_epoch: Option<u64>,
    /// Its components, by name.
    pub components: BTreeMap<ComponentId, ComponentView>,
    /// The sequence number last taken in of each of its keys, in the run `epoch`.
    seqs: FxHashMap<Key, u64>,
}

/// A change the mirror saw that matters to the executive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Change {
    /// A component's status changed.
    Status {
        /// The PEIS.
        peis: PeisId,
        /// The component.
        component: ComponentId,
        /// The new status.
        status: String,
    },
    /// The PEIS started a new run (it restarted): its components start afresh.
    Restarted {
        /// The PEIS.
        peis: PeisId,
    },
    /// A component wrote what it observed (`C.observed`).
    Observed {
        /// The PEIS.
        peis: PeisId,
        /// The component.
        component: ComponentId,
        /// The literals it wrote, as text.
        literals: String,
    },
    /// Who holds a component changed (`components.C.holders`).
    Holders {
        /// The PEIS.
        peis: PeisId,
        /// The component.
        component: ComponentId,
    },
    /// Anything else (types, costs, on/off, causes).
    Other,
}

/// The executive's mirror of the ecology's tuples.
#[derive(Debug, Clone, Default)]
pub struct Mirror {
    peis: BTreeMap<PeisId, PeisView>,
    /// The executive's own PEIS name, once known: its own claims are not another's.
    me: Option<PeisId>,
}

impl Mirror {
    /// An empty mirror.
    pub fn new() -> Mirror {
        Mirror::default()
    }

    /// Tells the mirror the executive's own PEIS name, so that its claims are told apart from
    /// other executives'.
    pub fn acting_as(&mut self, me: PeisId) {
        self.me = Some(me);
    }

    /// The holders of component (`peis`, `component`) other than this executive.
    pub fn held_by_others(&self, peis: &str, component: &str) -> Vec<PeisId> {
        self.component(peis, component)
            .map(|c| {
                c.holders
                    .iter()
                    .filter(|h| Some(*h) != self.me.as_ref())
                    .cloned()
                    .collect()
            })
            .unwrap_or_default()
    }

    /// Every PEIS seen.
    pub fn peis(&self) -> &BTreeMap<PeisId, PeisView> {
        &self.peis
    }

    /// One component, if seen.
    pub fn component(&self, peis: &str, component: &str) -> Option<&ComponentView> {
        self.peis.get(peis)?.components.get(component)
    }

    /// A PEIS joined.
    pub fn joined(&mut self, peis: &PeisId) {
        let view = self.peis.entry(peis.clone()).or_default();
        view.present = true;
        view.left_epoch = None;
    }

    /// A PEIS left: it is absent until it joins again or publishes from a later run.
    ///
    /// The versions seen are kept: a PEIS that was only cut off (frozen, or its network lost) comes
    /// back with the same run and continues its numbering, so its old tuples still read as old.
    pub fn left(&mut self, peis: &PeisId) {
        if let Some(view) = self.peis.get_mut(peis) {
            view.present = false;
            view.left_epoch = Some(view.epoch);
        }
    }

    /// Applies a tuple update of version (`epoch`, `seq`); returns what changed, nothing when the
    /// update is a duplicate, out of order or from an earlier run of its owner.
    pub fn apply(
        &mut self,
        owner: &PeisId,
        key: &Key,
        value: &str,
        epoch: u64,
        seq: u64,
    ) -> Changes {
        let mut changes = Changes::default();
        let view = self.peis.entry(owner.clone()).or_default();
        // Epoch 0 is a writer that does not say (a plain Zenoh put): its updates are not ordered by run.
        if epoch != 0 && view.epoch != 0 && epoch < view.epoch {
            return changes;
        }
        if epoch != 0 && epoch > view.epoch {
            if view.epoch != 0 {
                view.components.clear();
                view.seqs.clear();
                changes.restarted = Some(Change::Restarted {
                    peis: owner.clone(),
                });
            }
            view.epoch = epoch;
        }
        let slot = view.seqs.entry(key.clone()).or_insert(0);
        if seq <= *slot && *slot != 0 {
            return changes;
        }
        *slot = seq;
        // A late tuple of a run that has left does not bring the PEIS back; presence or a new run does.
        if view.left_epoch.is_none_or(|left| epoch > left) {
            view.present = true;
            view.left_epoch = None;
        }
        changes.update = view.update(owner, key, value);
        changes
    }

    /// The ecology state: `(peis P)` for present PEIS, and for each of their
    /// components with a known type `(pc P TYPE C)`, `(cost P C N on|off)`,
    /// `(status P C S)`, `(covers P C PLACE)` for each place it sees and, for each other
    /// executive that holds it,
    /// `(held P C HOLDER FUNCTIONALITY ARG…)` with the instance it runs
    /// (`idle` when it runs none), plus the given world facts. With `types`, only the components
    /// of those types are in it: a goal whose methods name the types they can use
    /// ([`ecology_config::component_types`]) is planned the same without the others, and in a
    /// building most components are of types a given goal cannot use.
    pub fn state(&self, world: &EcologyState, types: Option<&BTreeSet<String>>) -> EcologyState {
        // Each name's text made once for the whole state, not once for every fact it is in.
        let mut words = Words::default();
        let [peis, pc, cost, status, held, covers, on, off, idle] = [
            "peis", "pc", "cost", "status", "held", "covers", "on", "off", "idle",
        ]
        .map(Name::from);
        let mut state = EcologyState::with_capacity(8 * self.peis.len() + world.facts().len());
        let fact = |predicate: &Name, args: Vec<Name>| Fact {
            predicate: predicate.clone(),
            args,
        };
        for (name, view) in &self.peis {
            if !view.present {
                continue;
            }
            let p = name.shared();
            state.insert(fact(&peis, vec![p.clone()]));
            for (c, comp) in &view.components {
                let Some(ty) = &comp.ty else { continue };
                if types.is_some_and(|types| !types.contains(ty.as_str())) {
                    continue;
                }
                let c = c.shared();
                state.insert(fact(&pc, vec![p.clone(), words.of(ty), c.clone()]));
                if let Some(n) = comp.cost {
                    let power = if comp.on { &on } else { &off };
                    let args = vec![p.clone(), c.clone(), words.number(n), power.clone()];
                    state.insert(fact(&cost, args));
                }
                if let Some(s) = &comp.status {
                    state.insert(fact(&status, vec![p.clone(), c.clone(), words.of(s)]));
                }
                for place in &comp.covers {
                    state.insert(fact(&covers, vec![p.clone(), c.clone(), words.of(place)]));
                }
                for holder in comp.holders.iter().filter(|h| Some(*h) != self.me.as_ref()) {
                    let params = comp.params.as_deref().unwrap_or("");
                    let instance = params.trim().trim_start_matches('(').trim_end_matches(')');
                    let mut args = vec![p.clone(), c.clone(), holder.shared().clone()];
                    args.extend(instance.split_whitespace().map(Name::from));
                    if args.len() == 3 {
                        args.push(idle.clone());
                    }
                    state.insert(fact(&held, args));
                }
            }
        }
        for fact in world.facts() {
            state.insert(fact.clone());
        }
        state
    }

    /// The components of present PEIS that report `error`, with their cause.
    pub fn in_error(&self) -> Vec<(PeisId, ComponentId, String)> {
        self.peis
            .iter()
            .filter(|(_, view)| view.present)
            .flat_map(|(p, view)| {
                view.components
                    .iter()
                    .filter(|(_, comp)| comp.status.as_deref() == Some("error"))
                    .map(move |(c, comp)| {
                        let cause = comp.cause.clone().unwrap_or_default();
                        (p.clone(), c.clone(), cause)
                    })
            })
            .collect()
    }

    /// Counts of present PEIS and of their typed components.
    pub fn counts(&self) -> (usize, usize) {
        let present: Vec<&PeisView> = self.peis.values().filter(|v| v.present).collect();
        let components = present
            .iter()
            .map(|v| v.components.values().filter(|c| c.ty.is_some()).count())
            .sum();
        (present.len(), components)
    }
}

impl PeisView {
    /// Takes in tuple `key` = `value` of this PEIS (`owner`).
    fn update(&mut self, owner: &PeisId, key: &Key, value: &str) -> Option<Change> {
        let value = value.trim();
        // Keys outside the contract's fixed fields (outputs, inputs, anything else) change nothing here.
        let Some((name, field)) = ComponentField::parse_str(key.as_str()) else {
            return Some(Change::Other);
        };
        // A component known already keeps its name: only a new one's is checked and made.
        let component = match self.components.get_key_value(name) {
            Some((component, _)) => component.clone(),
            None => ComponentId::new(name).ok()?,
        };
        let c = self.components.entry(component.clone()).or_default();
        match field {
            ComponentField::Type => c.ty = Some(value.to_string()),
            ComponentField::Cost => c.cost = value.parse().ok(),
            ComponentField::CurrState => c.on = value == "on",
            ComponentField::ReqState => {}
            ComponentField::Holders => {
                c.holders = ecology_tuples::claims::parse_holders(value);
                return Some(Change::Holders {
                    peis: owner.clone(),
                    component,
                });
            }
            ComponentField::Status => {
                c.status = Some(value.to_string());
                return Some(Change::Status {
                    peis: owner.clone(),
                    component,
                    status: value.to_string(),
                });
            }
            ComponentField::Cause => c.cause = Some(value.to_string()),
            ComponentField::Params => c.params = Some(value.to_string()),
            ComponentField::Covers => {
                c.covers = value.split_whitespace().map(str::to_string).collect();
            }
            ComponentField::Observed => {
                return Some(Change::Observed {
                    peis: owner.clone(),
                    component,
                    literals: value.to_string(),
                });
            }
        }
        Some(Change::Other)
    }
}

/// The words of a state (types, statuses, costs), each made once.
#[derive(Default)]
struct Words<'a> {
    text: FxHashMap<&'a str, Name>,
    numbers: FxHashMap<u64, Name>,
}

impl<'a> Words<'a> {
    fn of(&mut self, word: &'a str) -> Name {
        self.text
            .entry(word)
            .or_insert_with(|| Name::from(word))
            .clone()
    }

    fn number(&mut self, n: u64) -> Name {
        let name = self
            .numbers
            .entry(n)
            .or_insert_with(|| Name::from(n.to_string()));
        name.clone()
    }
}

/// What one update changed: that its PEIS restarted, then what the update itself changed.
#[derive(Debug, Default)]
pub struct Changes {
    restarted: Option<Change>,
    update: Option<Change>,
}

impl IntoIterator for Changes {
    type Item = Change;
    type IntoIter = std::iter::Chain<std::option::IntoIter<Change>, std::option::IntoIter<Change>>;

    fn into_iter(self) -> Self::IntoIter {
        self.restarted.into_iter().chain(self.update)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use ecology_domain::EcologyState;
    use ecology_tuples::{Key, PeisId};

    use super::Mirror;

    /// A state with the given types leaves out the components of other types, and only them;
    /// the rooms a component covers are facts of it, and a field it does not know is none.
    #[test]
    fn a_state_for_some_types_has_only_their_components() {
        let mut mirror = Mirror::new();
        let tuples = [
            ("hsm", "components.ca1.type", "cams"),
            ("hsm", "components.ca1.cost", "20"),
            ("hsm", "ca1.status", "running"),
            ("hsm", "components.ca1.covers", " kitchen  living-room "),
            // A key of the directory this reader does not know changes nothing: a later field.
            ("hsm", "components.ca1.mounting", "ceiling"),
            ("app-7", "components.pl1.type", "player"),
            ("app-7", "components.pl1.covers", "kitchen"),
            ("app-7", "components.pl1.cost", "5"),
            ("app-7", "pl1.status", "idle"),
        ];
        for (seq, (owner, key, value)) in (1..).zip(tuples) {
            let owner = PeisId::new(owner).expect("a name");
            mirror.joined(&owner);
            let _ = mirror.apply(&owner, &Key::new(key).expect("a key"), value, 1, seq);
        }
        let text = |state: EcologyState| {
            let mut facts: Vec<String> = state.facts().iter().map(ToString::to_string).collect();
            facts.sort();
            facts.join(" ")
        };
        let all = text(mirror.state(&EcologyState::default(), None));
        assert_eq!(
            all,
            "(cost app-7 pl1 5 off) (cost hsm ca1 20 off) (covers app-7 pl1 kitchen) \
             (covers hsm ca1 kitchen) (covers hsm ca1 living-room) (pc app-7 player pl1) \
             (pc hsm cams ca1) (peis app-7) (peis hsm) (status app-7 pl1 idle) \
             (status hsm ca1 running)"
        );
        let cams = BTreeSet::from(["cams".to_string()]);
        let some = text(mirror.state(&EcologyState::default(), Some(&cams)));
        assert_eq!(
            some,
            "(cost hsm ca1 20 off) (covers hsm ca1 kitchen) (covers hsm ca1 living-room) \
             (pc hsm cams ca1) (peis app-7) (peis hsm) (status hsm ca1 running)"
        );
    }
}
