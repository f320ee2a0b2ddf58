//! Claims: who holds each component, arbitrated by the PEIS that owns it.
//!
//! Several executives may share one ecology. A component's PEIS is the only writer of its
//! tuples, so it is the one place that can decide, without a distributed lock, whether a remote
//! set of one of a component's *claim keys* (`components.C.reqState`, `C.params`, an input
//! `C.mi-INFO…`) may be applied, in the order the requests arrive:
//!
//! - **free** (nobody else holds it): applied; the requester becomes a holder;
//! - **the same** as what runs (`on` while it is on, the params it runs; for an input, the
//!   producer it already reads, asked by one that holds it already, since params come before
//!   wiring): *shared*, the requester joins the holders, and nothing else is written, so the
//!   running body is not restarted;
//! - **anything else**: refused, naming the holders ([`held_by`] reads the reason back).
//!
//! A release (`reqState` `off`, empty `params`) only removes its requester from the holders
//! while others still hold the component: nobody releases what another holds. The last holder's
//! release puts the component back the way the first claim found it: `reqState` `off` if a
//! request switched it on, params cleared (its wiring stays, as harmless as before). The holders are the tuple `components.C.holders`
//! (names separated by spaces, in the order they claimed), so whoever acquires the ecology's
//! state sees who holds what. The owner drops a holder that is gone with [`release_holder`].
//!
//! These rules are pure functions of the owner's own tuples; each implementation of the space
//! applies their writes atomically with the request.

use crate::contract::ComponentField;
use crate::model::{Tuple, Value};
use crate::name::{ComponentId, Key, PeisId};

/// The words that start the reason of a request refused because others hold the component.
const HELD_BY: &str = "held by ";

/// What a remote set to a claim key comes to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Arbitration {
    /// Write these tuples, in order (possibly none: a share already recorded, or a release of
    /// nothing). The request itself is among them when it is applied as asked.
    Apply(Vec<(Key, Value)>),
    /// Refused, with the reason (starting `held by HOLDER…:`).
    Refuse(String),
}

/// The component a key claims, and how: `None` for a key that is no claim key.
fn claim_target(key: &Key) -> Option<(ComponentId, Claim)> {
    if let Some((c, field)) = ComponentField::parse(key) {
        return match field {
            ComponentField::ReqState => Some((c, Claim::Power)),
            ComponentField::Params => Some((c, Claim::Params)),
            _ => None,
        };
    }
    let (component, rest) = key.as_str().split_once('.')?;
    rest.starts_with("mi-")
        .then(|| ComponentId::new(component).ok())
        .flatten()
        .map(|c| (c, Claim::Input))
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Claim {
    Power,
    Params,
    Input,
}

/// The holders a `components.C.holders` text names, in order; names that are not valid are skipped.
pub fn parse_holders(text: &str) -> Vec<PeisId> {
    text.split_whitespace()
        .filter_map(|name| PeisId::new(name).ok())
        .collect()
}

/// The holders named by the reason of a refused remote set, when others holding the component
/// was the reason: `held by exec-bob: tr1 runs (tracking-system hsm tr1 bob)`.
pub fn held_by(reason: &str) -> Option<Vec<PeisId>> {
    let start = reason.find(HELD_BY)?;
    let rest = &reason[start + HELD_BY.len()..];
    let names = rest.split_once(':').map_or(rest, |(names, _)| names);
    let holders = parse_holders(names);
    (!holders.is_empty()).then_some(holders)
}

fn holders_value(holders: &[PeisId]) -> Value {
    let names: Vec<&str> = holders.iter().map(PeisId::as_str).collect();
    Value::text(names.join(" "))
}

fn text_of(tuple: Option<&Tuple>) -> &str {
    tuple
        .and_then(|t| std::str::from_utf8(&t.data).ok())
        .unwrap_or("")
        .trim()
}

/// Decides a remote set of `key` to `value` from `requester` (`None`: a request that names
/// nobody, which may use a free component but never joins its holders), given the owner's
/// current tuples (`current`).
pub fn arbitrate<'a>(
    requester: Option<&PeisId>,
    key: &Key,
    value: &Value,
    current: impl Fn(&Key) -> Option<&'a Tuple>,
) -> Arbitration {
    let Some((c, claim)) = claim_target(key) else {
        return Arbitration::Apply(vec![(key.clone(), value.clone())]);
    };
    let holders_key = ComponentField::Holders.key(&c);
    let holders = parse_holders(text_of(current(&holders_key)));
    let others: Vec<&PeisId> = holders.iter().filter(|h| Some(*h) != requester).collect();
    let asked = std::str::from_utf8(&value.data).unwrap_or("").trim();
    let release = match claim {
        Claim::Power => asked == "off",
        Claim::Params => asked.is_empty(),
        Claim::Input => false,
    };
    let mut writes = Vec::new();
    if release {
        let remaining: Vec<PeisId> = others.iter().map(|h| (*h).clone()).collect();
        if !remaining.is_empty() {
            // Nobody releases what another holds: only the requester leaves.
            if remaining.len() != holders.len() {
                writes.push((holders_key, holders_value(&remaining)));
            }
            return Arbitration::Apply(writes);
        }
        writes.push((key.clone(), value.clone()));
        if !holders.is_empty() {
            // The last holder leaves: the component goes back the way the first claim found it.
            writes.extend(put_back(&c, claim, &current));
            writes.push((holders_key, holders_value(&[])));
        }
        return Arbitration::Apply(writes);
    }
    if !others.is_empty() {
        let now = current(key);
        let same = match claim {
            Claim::Power => {
                text_of(now) == "on" || text_of(current(&ComponentField::CurrState.key(&c))) == "on"
            }
            Claim::Params => text_of(now) == asked,
            // An executive gives params before it wires: one that does not hold the component
            // by now was refused its params, and wiring alone must not make it a holder.
            Claim::Input => {
                requester.is_some_and(|r| holders.contains(r))
                    && now.is_some_and(|t| t.data == value.data)
            }
        };
        if !same {
            let names: Vec<&str> = others.iter().map(|h| h.as_str()).collect();
            let what = match claim {
                Claim::Power => format!("{c} is off"),
                Claim::Params => match text_of(now) {
                    "" => format!("{c} runs nothing"),
                    params => format!("{c} runs {params}"),
                },
                Claim::Input => format!("{key} reads {}", text_of(now)),
            };
            return Arbitration::Refuse(format!("{HELD_BY}{}: {what}", names.join(" ")));
        }
    } else {
        writes.push((key.clone(), value.clone()));
    }
    if let Some(requester) = requester.filter(|r| !holders.contains(r)) {
        let mut joined = holders.clone();
        joined.push(requester.clone());
        writes.push((holders_key, holders_value(&joined)));
    }
    Arbitration::Apply(writes)
}

/// The writes that put component `c` back once its last holder is gone, besides the releasing
/// request's own (`released`): `reqState` `off` if a remote set switched it on, and params
/// cleared, so that nothing a task gave it outlives the task.
fn put_back<'a>(
    c: &ComponentId,
    released: Claim,
    current: &impl Fn(&Key) -> Option<&'a Tuple>,
) -> Vec<(Key, Value)> {
    let mut writes = Vec::new();
    let req = ComponentField::ReqState.key(c);
    let switched_on =
        current(&req).is_some_and(|t| t.creator.is_some()) && text_of(current(&req)) == "on";
    if released != Claim::Power && switched_on {
        writes.push((req, Value::text("off")));
    }
    let params = ComponentField::Params.key(c);
    if released != Claim::Params && !text_of(current(&params)).is_empty() {
        writes.push((params, Value::text("")));
    }
    writes
}

/// The writes that drop `holder` from every component it holds among `holder_tuples` (the
/// owner's `components.*.holders` tuples), putting back each component it was the last to hold.
pub fn release_holder<'a>(
    holder: &PeisId,
    holder_tuples: impl IntoIterator<Item = &'a Tuple>,
    current: impl Fn(&Key) -> Option<&'a Tuple>,
) -> Vec<(Key, Value)> {
    let mut writes = Vec::new();
    for tuple in holder_tuples {
        let Some((c, ComponentField::Holders)) = ComponentField::parse(&tuple.key) else {
            continue;
        };
        let holders = parse_holders(text_of(Some(tuple)));
        if !holders.contains(holder) {
            continue;
        }
        let remaining: Vec<PeisId> = holders.into_iter().filter(|h| h != holder).collect();
        if remaining.is_empty() {
            // `Input` releases no field itself, so both are put back.
            writes.extend(put_back(&c, Claim::Input, &current));
        }
        writes.push((tuple.key.clone(), holders_value(&remaining)));
    }
    writes
}
