//! The ecology state: ground facts about PEIS, components, costs and the world.
//!
//! Built by the executive from the live tuple space, or read from a `.facts`
//! file of S-expressions like `(pc astrid laser l1)`. Facts with a fixed
//! meaning (`peis`, `pc`, `cost`, `status`, `channel-cost`) are checked when read.

use std::fmt;
use std::hash::BuildHasher;

use hashbrown::HashTable;
use rustc_hash::FxBuildHasher;

use crate::diagnostic::{Diagnostic, Span};
use crate::model::{Name, write_call};
use crate::validate::ECOLOGY_PREDICATES;

/// A ground fact: `(cost astrid l1 100 off)`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Fact {
    /// The predicate.
    pub predicate: Name,
    /// Its ground arguments.
    pub args: Vec<Name>,
}

impl Fact {
    /// A fact from a predicate and arguments.
    pub fn new(predicate: &str, args: &[&str]) -> Fact {
        Fact {
            predicate: predicate.into(),
            args: args.iter().map(|&a| a.into()).collect(),
        }
    }
}

impl fmt::Display for Fact {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_call(f, &self.predicate, &self.args)
    }
}

/// Whether a component is running.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Power {
    /// Running: its cost is its running cost.
    On,
    /// Not running: its cost is its start-up cost.
    Off,
}

impl fmt::Display for Power {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Power::On => "on",
            Power::Off => "off",
        })
    }
}

/// What the state says a component costs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ComponentCost {
    /// Running cost when on, start-up cost when off.
    pub amount: u64,
    /// Whether it is on.
    pub power: Power,
}

impl ComponentCost {
    /// What the last two arguments of a `(cost PEIS COMPONENT AMOUNT POWER)` fact say; `None`
    /// when the amount is not a number. Any power but `on` is off.
    pub fn read(amount: &str, power: &str) -> Option<ComponentCost> {
        Some(ComponentCost {
            amount: amount.parse().ok()?,
            power: match power {
                "on" => Power::On,
                _ => Power::Off,
            },
        })
    }
}

/// A set of ground facts, in insertion order without duplicates.
#[derive(Debug, Clone, Default)]
pub struct EcologyState {
    facts: Vec<Fact>,
    /// Where each fact is in `facts`, by its hash: each fact is stored once.
    seen: HashTable<u32>,
}

impl PartialEq for EcologyState {
    fn eq(&self, other: &EcologyState) -> bool {
        self.facts == other.facts
    }
}

fn fact_hash(fact: &Fact) -> u64 {
    FxBuildHasher.hash_one(fact)
}

impl EcologyState {
    /// An empty state.
    pub fn new() -> EcologyState {
        EcologyState::default()
    }

    /// An empty state with room for `facts` facts.
    pub fn with_capacity(facts: usize) -> EcologyState {
        EcologyState {
            facts: Vec::with_capacity(facts),
            seen: HashTable::with_capacity(facts),
        }
    }

    /// Adds a fact; returns false if it was already there.
    pub fn insert(&mut self, fact: Fact) -> bool {
        let hash = fact_hash(&fact);
        if self.find(hash, &fact) {
            return false;
        }
        let at = u32::try_from(self.facts.len()).expect("fewer than 2^32 facts");
        let facts = &self.facts;
        self.seen
            .insert_unique(hash, at, |&at| fact_hash(&facts[at as usize]));
        self.facts.push(fact);
        true
    }

    /// Whether the fact holds.
    pub fn contains(&self, fact: &Fact) -> bool {
        self.find(fact_hash(fact), fact)
    }

    /// Whether `fact`, whose hash is `hash`, is stored.
    fn find(&self, hash: u64, fact: &Fact) -> bool {
        self.seen
            .find(hash, |&at| self.facts[at as usize] == *fact)
            .is_some()
    }

    /// All facts, in insertion order.
    pub fn facts(&self) -> &[Fact] {
        &self.facts
    }

    /// Facts of one predicate.
    pub fn with_predicate<'a>(&'a self, predicate: &'a str) -> impl Iterator<Item = &'a Fact> {
        self.facts
            .iter()
            .filter(move |f| &*f.predicate == predicate)
    }

    /// The `cost` fact of component `component` on `peis`.
    pub fn component_cost(&self, peis: &str, component: &str) -> Option<ComponentCost> {
        self.with_predicate("cost").find_map(|f| match &f.args[..] {
            [p, c, amount, power] if &**p == peis && &**c == component => {
                ComponentCost::read(amount, power)
            }
            _ => None,
        })
    }

    /// The `channel-cost` from one PEIS to another, if the state gives one.
    pub fn channel_cost(&self, from: &str, to: &str) -> Option<u64> {
        self.with_predicate("channel-cost")
            .find_map(|f| match &f.args[..] {
                [a, b, n] if &**a == from && &**b == to => n.parse().ok(),
                _ => None,
            })
    }

    /// The number of facts.
    pub fn len(&self) -> usize {
        self.facts.len()
    }

    /// Whether there are no facts.
    pub fn is_empty(&self) -> bool {
        self.facts.is_empty()
    }
}

impl FromIterator<Fact> for EcologyState {
    fn from_iter<I: IntoIterator<Item = Fact>>(iter: I) -> EcologyState {
        let mut state = EcologyState::new();
        for fact in iter {
            state.insert(fact);
        }
        state
    }
}

impl fmt::Display for EcologyState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for fact in &self.facts {
            writeln!(f, "{fact}")?;
        }
        Ok(())
    }
}

/// Checks a fact with a fixed meaning; returns the problem, if any.
pub(crate) fn check_fact(fact: &Fact, span: Span) -> Option<Diagnostic> {
    // Another executive's claim: the component, its holder, and the instance it runs.
    if &*fact.predicate == "held" && fact.args.len() < 4 {
        return Some(
            Diagnostic::error(
                span,
                format!(
                    "wrong arity: `held` takes at least 4 arguments, given {}",
                    fact.args.len()
                ),
            )
            .with_note("usage: (held PEIS COMPONENT HOLDER FUNCTIONALITY ARG…)"),
        );
    }
    let arity = ECOLOGY_PREDICATES
        .iter()
        .find(|(name, _)| *name == &*fact.predicate)
        .map(|&(_, arity)| arity)?;
    if fact.args.len() != arity {
        return Some(
            Diagnostic::error(
                span,
                format!(
                    "wrong arity: `{}` takes {arity} arguments, given {}",
                    fact.predicate,
                    fact.args.len()
                ),
            )
            .with_note(usage(&fact.predicate)),
        );
    }
    let natural = |text: &str| text.parse::<u64>().is_ok();
    match (&*fact.predicate, &fact.args[..]) {
        ("cost", [_, _, amount, _]) if !natural(amount) => Some(
            Diagnostic::error(
                span,
                format!("cost `{amount}` is not a non-negative integer"),
            )
            .with_note(usage("cost")),
        ),
        ("cost", [_, _, _, power]) if !matches!(&**power, "on" | "off") => Some(
            Diagnostic::error(
                span,
                format!("component state `{power}` is neither `on` nor `off`"),
            )
            .with_note(usage("cost")),
        ),
        ("channel-cost", [_, _, amount]) if !natural(amount) => Some(
            Diagnostic::error(
                span,
                format!("cost `{amount}` is not a non-negative integer"),
            )
            .with_note(usage("channel-cost")),
        ),
        _ => None,
    }
}

fn usage(predicate: &str) -> &'static str {
    match predicate {
        "peis" => "usage: (peis PEIS)",
        "pc" => "usage: (pc PEIS TYPE COMPONENT)",
        "cost" => "usage: (cost PEIS COMPONENT AMOUNT on|off)",
        "status" => "usage: (status PEIS COMPONENT STATUS)",
        _ => "usage: (channel-cost FROM-PEIS TO-PEIS AMOUNT)",
    }
}
