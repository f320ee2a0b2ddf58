//! The ground-truth check of several executives in one ecology: no component
//! serves two executives with different params, and no executive's input is
//! re-pointed to what another wired.
//!
//! A pure fold over what a run saw, in the order it happened: each
//! executive's log (what its configuration asks of each component) and every
//! change of the components' `C.params` and `C.mi-INFO` tuples (what the
//! components really ran and read). An executive *uses* a component from the
//! moment the component runs the params its current configuration gives it
//! (at once when it already did) until its configuration no longer names the
//! component, the component stops running those params, or its task ends.
//! Its own new configuration replaces its old one, so its make-before-break
//! is never a conflict; a configuration whose request was refused (another
//! held the component) never uses the component, so losing a race is not one
//! either.

use std::collections::BTreeMap;
use std::time::Duration;

use ecology_exec::LogEvent;

/// A component: its PEIS and its name there.
type Component = (String, String);

/// What an executive's current configuration asks of one component.
#[derive(Debug, Clone, PartialEq)]
struct Use {
    /// The params it gives the component: its functionality instance.
    params: String,
    /// Whether the component has run those params since the configuration was
    /// chosen: only then does the executive use it (a refused request never does).
    running: bool,
    /// The values its wiring gives the component's inputs, by information
    /// name (`global-pos`): `(meta PEIS PRODUCER.out.INFO)`.
    inputs: BTreeMap<String, Vec<String>>,
}

/// One change of a tuple of the ecology (a removal is an empty value).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Change<'a> {
    /// The tuple's owner.
    pub owner: &'a str,
    /// Its key.
    pub key: &'a str,
    /// Its new value, empty when removed.
    pub value: &'a str,
    /// The owner's run that wrote it: a later run is a restart.
    pub epoch: u64,
    /// Who asked for it by remote set, when someone did.
    pub creator: Option<&'a str>,
}

/// The check, fed in the order things happened (see the module documentation).
#[derive(Debug, Default)]
pub(crate) struct ConflictCheck {
    /// Each executive's current configuration, by component.
    uses: BTreeMap<String, BTreeMap<Component, Use>>,
    /// What each component runs now (its `C.params`), by the ground truth.
    params: BTreeMap<Component, String>,
    /// Each PEIS's latest run seen.
    epochs: BTreeMap<String, u64>,
    /// The conflicts found, one line each.
    found: Vec<String>,
}

/// The information name of a channel's information text: `image` of `(image hsm)`.
fn info_name(info: &str) -> &str {
    info.trim()
        .trim_start_matches('(')
        .split([' ', ')'])
        .next()
        .unwrap_or("")
}

impl ConflictCheck {
    /// `executive` logged `event`.
    pub(crate) fn logged(&mut self, executive: &str, event: &LogEvent) {
        match event {
            LogEvent::Configuration {
                functionalities, ..
            } => {
                let mut uses = BTreeMap::new();
                for instance in functionalities {
                    let at = &instance.component;
                    let key = (at.peis.to_string(), at.component.to_string());
                    let params = instance.call.trim().to_string();
                    let running = self.params.get(&key) == Some(&params);
                    uses.insert(
                        key,
                        Use {
                            params,
                            running,
                            inputs: BTreeMap::new(),
                        },
                    );
                }
                self.uses.insert(executive.to_string(), uses);
            }
            LogEvent::Deployed { channels, .. } => {
                let Some(uses) = self.uses.get_mut(executive) else {
                    return;
                };
                for channel in channels {
                    let (peis, producer) = (&channel.from.peis, &channel.from.component);
                    let (consumer_peis, consumer) = (&channel.to.peis, &channel.to.component);
                    let name = info_name(&channel.info);
                    let key = (consumer_peis.to_string(), consumer.to_string());
                    if let Some(used) = uses.get_mut(&key) {
                        used.inputs
                            .entry(name.to_string())
                            .or_default()
                            .push(format!("(meta {peis} {producer}.out.{name})"));
                    }
                }
            }
            LogEvent::Released { .. } | LogEvent::TaskDone | LogEvent::TaskFailed { .. } => {
                self.uses.remove(executive);
            }
            _ => {}
        }
    }

    /// A tuple changed at `t` (since the run started).
    pub(crate) fn changed(&mut self, t: Duration, change: Change<'_>) {
        let epoch = self
            .epochs
            .entry(change.owner.to_string())
            .or_insert(change.epoch);
        if change.epoch < *epoch {
            // A late tuple of an earlier run: it changes nothing the components run.
            return;
        }
        if change.epoch > *epoch {
            // The PEIS started again: its components run nothing of anyone's until given params.
            *epoch = change.epoch;
            self.params.retain(|(peis, _), _| peis != change.owner);
            for uses in self.uses.values_mut() {
                for ((peis, _), used) in uses.iter_mut() {
                    if peis == change.owner {
                        used.running = false;
                    }
                }
            }
        }
        let Some((component, field)) = change.key.split_once('.') else {
            return;
        };
        if component == "components" {
            // The init component's tuples (`components.C.reqState`, …).
            return;
        }
        let key = (change.owner.to_string(), component.to_string());
        let value = change.value.trim();
        let who = change.creator.unwrap_or("its own PEIS");
        // An executive's own request is no conflict between executives, even when it comes in
        // after the executive's next configuration: one that reconfigures twice in one instant
        // (a second failure while deploying) has its first requests still on their way, and the
        // PEIS applies its requests in the order they were sent, the later ones last.
        let another = |executive: &str| change.creator != Some(executive);
        if field == "params" {
            if !value.is_empty() {
                for (executive, uses) in &self.uses {
                    if let Some(used) = uses.get(&key)
                        && used.running
                        && used.params != value
                        && another(executive)
                    {
                        self.found.push(format!(
                            "{:.3}s {}:{component} ran {} for {executive} when {who} gave it {value}",
                            t.as_secs_f64(),
                            change.owner,
                            used.params,
                        ));
                    }
                }
            }
            for uses in self.uses.values_mut() {
                if let Some(used) = uses.get_mut(&key) {
                    used.running = !value.is_empty() && used.params == value;
                }
            }
            if value.is_empty() {
                self.params.remove(&key);
            } else {
                self.params.insert(key, value.to_string());
            }
        } else if let Some(input) = field.strip_prefix("mi-") {
            if value.is_empty() {
                return;
            }
            // `C.mi-INFO` or `C.mi-INFO.ARG…` (two inputs of one kind).
            let name = input.split('.').next().unwrap_or(input);
            for (executive, uses) in &self.uses {
                if let Some(used) = uses.get(&key)
                    && used.running
                    && let Some(wired) = used.inputs.get(name)
                    && !wired.iter().any(|w| w == value)
                    && another(executive)
                {
                    self.found.push(format!(
                        "{:.3}s {}:{component}'s input {name} was pointed at {value} by {who} while {executive} wires it to {}",
                        t.as_secs_f64(),
                        change.owner,
                        wired.join(" or "),
                    ));
                }
            }
        }
    }

    /// The conflicts found so far, one line each.
    pub(crate) fn conflicts(&self) -> &[String] {
        &self.found
    }
}
