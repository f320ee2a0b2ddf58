//! What the live view knows: built from tuple changes, presence, and the executive's log entries
//! (the JSON objects of `ecology task --json`, also published as the executive's `log` tuple),
//! and the home from the `world` PEIS' tuples ([`Home`]).

use std::collections::BTreeMap;

use ecology_exec::{LogChannel, LogComponent, LogEntry, LogEvent, LogFunctionality};
use ecology_tuples::world::WORLD;
use ecology_tuples::{PresenceEvent, TupleEvent};
use serde_json::{Value as Json, json};

use crate::home::Home;
use crate::log_json;
use crate::svg::{Drawing, Edge, Mark, Node};

/// The longest value preview kept per tuple.
const PREVIEW: usize = 160;
/// Timeline entries kept (the oldest go first).
const TIMELINE: usize = 400;
/// Tuples kept; past it, new keys are counted but not stored.
const MAX_TUPLES: usize = 20_000;

#[derive(Clone, Debug, Default)]
struct TupleRow {
    value: String,
    mimetype: String,
    seq: u64,
    changed: u64,
}

#[derive(Clone, Debug, Default)]
struct Configuration {
    goal: String,
    cost: u64,
    optimal: bool,
    reconfiguration: bool,
    functionalities: Vec<LogFunctionality>,
    channels: Vec<LogChannel>,
    switched_on: Vec<LogComponent>,
}

/// The ecology as the view sees it.
#[derive(Clone, Debug, Default)]
pub struct View {
    present: BTreeMap<String, bool>,
    tuples: BTreeMap<(String, String), TupleRow>,
    dropped_tuples: u64,
    plan: Vec<String>,
    current: Option<usize>,
    done: Vec<usize>,
    failed_actions: Vec<usize>,
    timeline: Vec<Json>,
    configuration: Option<Configuration>,
    failed: BTreeMap<LogComponent, String>,
    status: String,
    changes: u64,
    home: Home,
}

impl View {
    /// An empty view.
    pub fn new() -> Self {
        Self {
            status: "waiting for the executive".into(),
            ..Self::default()
        }
    }

    /// How many changes the view has taken in: a version for clients.
    pub fn version(&self) -> u64 {
        self.changes
    }

    /// Takes in a tuple change; the executive's `log` tuple is also read as a log entry.
    pub fn tuple(&mut self, event: &TupleEvent) {
        self.changes += 1;
        match event {
            TupleEvent::Changed(t) => {
                let text = String::from_utf8_lossy(&t.data);
                if t.key.as_str() == "log"
                    && let Some(logged) = log_json::decode_line(&text)
                {
                    self.log(&logged.entry, logged.executive.as_deref());
                }
                if t.owner.as_str() == WORLD {
                    self.home.tuple(t.key.as_str(), Some(&text));
                }
                let id = (t.owner.to_string(), t.key.to_string());
                if !self.tuples.contains_key(&id) && self.tuples.len() >= MAX_TUPLES {
                    self.dropped_tuples += 1;
                    return;
                }
                self.present.entry(t.owner.to_string()).or_insert(true);
                self.tuples.insert(
                    id,
                    TupleRow {
                        value: preview(&text),
                        mimetype: t.mimetype.to_string(),
                        seq: t.seq,
                        changed: t.ts_write.as_nanos(),
                    },
                );
            }
            TupleEvent::Removed { owner, key, .. } => {
                if owner.as_str() == WORLD {
                    self.home.tuple(key.as_str(), None);
                }
                self.tuples.remove(&(owner.to_string(), key.to_string()));
            }
            TupleEvent::Retargeted { .. } => {}
        }
    }

    /// Takes in a presence event.
    pub fn presence(&mut self, event: &PresenceEvent) {
        self.changes += 1;
        match event {
            PresenceEvent::Joined(p) => {
                self.present.insert(p.to_string(), true);
            }
            PresenceEvent::Left(p) => {
                self.present.insert(p.to_string(), false);
            }
        }
    }

    /// Takes in one entry of the executive's log, logged by `executive` when it is named (a run
    /// of several tasks). The timeline says what the text timeline says.
    pub fn log(&mut self, entry: &LogEntry, executive: Option<&str>) {
        self.changes += 1;
        let mut cost = Json::Null;
        match &entry.event {
            LogEvent::Plan { actions, .. } | LogEvent::Replanned { actions, .. } => {
                self.plan.clone_from(actions);
                self.current = None;
                self.done.clear();
                self.failed_actions.clear();
            }
            LogEvent::ActionStarted { index, action } => {
                self.current = Some(*index);
                self.status = format!("action {}: {action}", index + 1);
            }
            LogEvent::Branch { actions, .. } => {
                // The plan goes on with the branch's actions after the current one.
                let upto = self.current.map_or(self.plan.len(), |i| i + 1);
                self.plan.truncate(upto);
                self.plan.extend(actions.iter().cloned());
            }
            LogEvent::ActionDone { index, .. } => self.done.push(*index),
            LogEvent::ActionFailed { index, .. } => self.failed_actions.push(*index),
            LogEvent::Configuration {
                goal,
                cost: chosen,
                optimal,
                functionalities,
                reconfiguration,
                ..
            } => {
                cost = json!(chosen);
                self.configuration = Some(Configuration {
                    goal: goal.clone(),
                    cost: *chosen,
                    optimal: *optimal,
                    reconfiguration: *reconfiguration,
                    functionalities: functionalities.clone(),
                    channels: Vec::new(),
                    switched_on: Vec::new(),
                });
            }
            LogEvent::Deployed {
                switched_on,
                channels,
            } => {
                if let Some(c) = &mut self.configuration {
                    c.channels.clone_from(channels);
                    c.switched_on.clone_from(switched_on);
                }
            }
            LogEvent::Failure {
                peis,
                component,
                cause,
            } => {
                self.failed.insert(
                    LogComponent::new(peis.as_str(), component.as_str()),
                    cause.clone(),
                );
            }
            LogEvent::TaskDone => {
                self.status = "task done".into();
                self.current = None;
            }
            LogEvent::TaskFailed { reason } => {
                self.status = format!("task failed: {reason}");
            }
            _ => {}
        }
        // The timeline's text, each line without the indentation that lays it out in a terminal.
        let text = entry
            .event
            .to_string()
            .lines()
            .map(str::trim_start)
            .collect::<Vec<_>>()
            .join("\n");
        let text = match executive {
            Some(executive) => format!("[{executive}] {text}"),
            None => text,
        };
        self.timeline.push(json!({
            "t": entry.t.as_secs_f64(),
            "event": entry.event.name(),
            "executive": executive,
            "text": text,
            "cost": cost,
        }));
        if self.timeline.len() > TIMELINE {
            let extra = self.timeline.len() - TIMELINE;
            self.timeline.drain(..extra);
        }
    }

    /// The current configuration as a drawing: its functionalities and channels, with the
    /// components that failed during the run marked beside them.
    pub fn drawing(&self) -> Option<Drawing> {
        let c = self.configuration.as_ref()?;
        let mut drawing = Drawing {
            title: format!(
                "{}: cost {}{}",
                c.goal,
                c.cost,
                if c.optimal { " (optimal)" } else { "" }
            ),
            nodes: Vec::new(),
            edges: Vec::new(),
        };
        for f in &c.functionalities {
            let (peis, component) = (&*f.component.peis, &*f.component.component);
            let state = self
                .component_field(peis, component, "currState")
                .unwrap_or_else(|| "in use".into());
            // Who holds it, when it is shared with other executives' tasks.
            let holders = self
                .component_field(peis, component, "holders")
                .filter(|h| h.split_whitespace().count() > 1);
            drawing.nodes.push(Node {
                peis: peis.to_owned(),
                component: component.to_owned(),
                label: f.call.clone(),
                detail: match holders {
                    Some(h) => format!(
                        "{state}, shared: {}",
                        h.split_whitespace().collect::<Vec<_>>().join(", ")
                    ),
                    None => state,
                },
                mark: if c.switched_on.contains(&f.component) {
                    Mark::SwitchedOn
                } else {
                    Mark::Normal
                },
            });
        }
        for channel in &c.channels {
            let find = |at: &LogComponent| drawing.node(&at.peis, &at.component);
            if let (Some(from), Some(to)) = (find(&channel.from), find(&channel.to)) {
                drawing.edges.push(Edge {
                    from,
                    to,
                    info: channel.info.to_string(),
                });
            }
        }
        for (at, cause) in &self.failed {
            if drawing.node(&at.peis, &at.component).is_none() {
                drawing.nodes.push(Node {
                    peis: at.peis.to_string(),
                    component: at.component.to_string(),
                    label: format!("FAILED {at}"),
                    detail: cause.clone(),
                    mark: Mark::Failed,
                });
            }
        }
        Some(drawing)
    }

    fn component_field(&self, peis: &str, component: &str, field: &str) -> Option<String> {
        self.tuples
            .get(&(peis.to_owned(), format!("components.{component}.{field}")))
            .map(|row| row.value.clone())
    }

    /// Everything the page shows, as one JSON object.
    pub fn snapshot(&self) -> Json {
        let mut peis: Vec<Json> = Vec::new();
        for (name, present) in &self.present {
            let mut components: BTreeMap<String, Json> = BTreeMap::new();
            for ((owner, key), row) in self.tuples.range((name.clone(), String::new())..) {
                if owner != name {
                    break;
                }
                let parts: Vec<&str> = key.split('.').collect();
                let (component, field) = match parts.as_slice() {
                    ["components", c, field] => (*c, *field),
                    [c, field @ ("status" | "cause")] => (*c, *field),
                    _ => continue,
                };
                let entry = components
                    .entry(component.to_owned())
                    .or_insert_with(|| json!({"id": component}));
                entry[field] = json!(row.value);
            }
            for (at, cause) in &self.failed {
                if *at.peis == **name
                    && let Some(entry) = components.get_mut(&*at.component)
                {
                    entry["failed"] = json!(cause);
                }
            }
            peis.push(json!({
                "name": name,
                "present": present,
                "components": components.into_values().filter(|c| c.get("type").is_some()).collect::<Vec<_>>(),
            }));
        }
        let tuples: Vec<Json> = self
            .tuples
            .iter()
            .map(|((owner, key), row)| {
                json!({"owner": owner, "key": key, "value": row.value, "mimetype": row.mimetype,
                       "seq": row.seq, "changed": row.changed})
            })
            .collect();
        let plan: Vec<Json> = self
            .plan
            .iter()
            .enumerate()
            .map(|(i, action)| {
                let state = if self.failed_actions.contains(&i) {
                    "failed"
                } else if self.done.contains(&i) {
                    "done"
                } else if self.current == Some(i) {
                    "current"
                } else {
                    "pending"
                };
                json!({"action": action, "state": state})
            })
            .collect();
        let configuration = self.configuration.as_ref().map(|c| {
            json!({"goal": c.goal, "cost": c.cost, "optimal": c.optimal,
                   "reconfiguration": c.reconfiguration})
        });
        json!({
            "version": self.changes,
            "status": self.status,
            "peis": peis,
            "plan": plan,
            "configuration": configuration,
            "svg": self.drawing().map(|d| d.svg()),
            "home": self.home.snapshot(),
            "failed": self
                .failed
                .iter()
                .map(|(at, cause)| (at.to_string(), json!(cause)))
                .collect::<serde_json::Map<_, _>>(),
            "timeline": self.timeline,
            "tuples": tuples,
            "tuples_not_kept": self.dropped_tuples,
        })
    }
}

fn preview(text: &str) -> String {
    if text.chars().count() <= PREVIEW {
        text.to_owned()
    } else {
        let mut s: String = text.chars().take(PREVIEW).collect();
        s.push('…');
        s
    }
}

#[cfg(test)]
mod tests {
    use ecology_tuples::{Key, Mimetype, PeisId, Timestamp, Tuple};

    use super::*;

    fn tuple(owner: &str, key: &str, value: &str) -> TupleEvent {
        TupleEvent::Changed(Tuple {
            owner: PeisId::new(owner).expect("name"),
            key: Key::new(key).expect("key"),
            data: value.as_bytes().to_vec().into(),
            mimetype: Mimetype::octet_stream(),
            ts_write: Timestamp(1),
            ts_user: None,
            expiry: None,
            seq: 1,
            epoch: 1,
            creator: None,
        })
    }

    /// An entry as `ecology task --json` writes it, read with the codec.
    fn entry(text: &str) -> LogEntry {
        log_json::decode_line(text).expect("a log entry").entry
    }

    /// The texts of a snapshot's timeline, in order.
    fn timeline_texts(snapshot: &Json) -> Vec<&str> {
        snapshot["timeline"]
            .as_array()
            .expect("timeline")
            .iter()
            .filter_map(|e| e["text"].as_str())
            .collect()
    }

    #[test]
    fn the_log_and_tuples_make_the_picture_of_a_reconfiguration() {
        let mut view = View::new();
        view.presence(&PresenceEvent::Joined(PeisId::new("hsm").expect("name")));
        for (owner, key, value) in [
            ("hsm", "components.tr1.type", "tr-sys"),
            ("hsm", "components.tr1.currState", "on"),
            ("hsm", "tr1.status", "error"),
            ("astrid", "components.l1.type", "laser"),
            ("astrid", "components.l1.currState", "on"),
        ] {
            view.tuple(&tuple(owner, key, value));
        }
        view.log(
            &entry(r#"{"event":"plan","actions":["(move astrid a b)"],"t":0.2}"#),
            None,
        );
        view.log(
            &entry(r#"{"event":"action_started","index":0,"action":"(move astrid a b)","t":0.2}"#),
            None,
        );
        view.log(&entry(
            r#"{"event":"failure","peis":"hsm","component":"tr1","cause":"no images","t":15.5}"#,
        ), None);
        // The executive's log tuple counts as a log entry too.
        view.tuple(&tuple(
            "executive",
            "log",
            r#"{"event":"configuration","goal":"(navigate astrid b)","cost":170,"optimal":true,"reconfiguration":true,"alternatives":[170,180],"functionalities":["(laser astrid l1) on astrid:l1","(navigation astrid tc1 b) on astrid:tc1"],"t":15.5}"#,
        ));
        view.log(&entry(r#"{"event":"deployed","channels":["astrid:l1 → astrid:tc1 (range-scan astrid)"],"switched_on":["astrid:l1"],"t":15.5}"#), None);

        // Several executives: who holds a component shows beside it, and a shared one says so.
        view.tuple(&tuple(
            "astrid",
            "components.l1.holders",
            "executive exec-bob",
        ));
        view.log(&entry(
            r#"{"event":"held","peis":"hsm","component":"tr1","holders":["exec-bob"],"t":15.6}"#,
        ), None);

        let snapshot = view.snapshot();
        let astrid = snapshot["peis"]
            .as_array()
            .and_then(|all| all.iter().find(|p| p["name"] == "astrid"))
            .expect("astrid listed");
        assert_eq!(astrid["components"][0]["holders"], "executive exec-bob");
        assert!(
            snapshot["svg"]
                .as_str()
                .is_some_and(|svg| svg.contains("on, shared: executive, exec-bob")),
            "{}",
            snapshot["svg"]
        );
        assert_eq!(snapshot["configuration"]["cost"], 170);
        assert_eq!(snapshot["plan"][0]["state"], "current");
        assert_eq!(snapshot["failed"]["hsm:tr1"], "no images");
        let hsm = snapshot["peis"]
            .as_array()
            .and_then(|all| all.iter().find(|p| p["name"] == "hsm"))
            .expect("hsm listed");
        assert_eq!(hsm["present"], true);
        assert_eq!(hsm["components"][0]["status"], "error");
        assert_eq!(hsm["components"][0]["failed"], "no images");
        let svg = snapshot["svg"].as_str().expect("svg");
        assert!(
            svg.contains("(navigate astrid b): cost 170 (optimal)"),
            "{svg}"
        );
        assert!(svg.contains(r#"class="functionality switched-on" data-component="astrid:l1""#));
        assert!(svg.contains(r#"class="failed" data-component="hsm:tr1""#));
        assert_eq!(svg.matches("class=\"channel\"").count(), 1);
        let texts = timeline_texts(&snapshot);
        assert_eq!(
            texts,
            [
                "plan: (move astrid a b)",
                "action 1: (move astrid a b)",
                "FAILURE hsm:tr1: no images",
                "reconfigured for (navigate astrid b): cost 170 (optimal; alternatives 170, 180)\n\
                 (laser astrid l1) on astrid:l1\n\
                 (navigation astrid tc1 b) on astrid:tc1",
                "deploy: switch on astrid:l1; 1 channels",
                "hsm:tr1 is held by exec-bob: done without until it is released",
            ]
        );
    }

    #[test]
    fn a_branch_of_a_conditional_plan_replaces_what_followed_the_sensing_action() {
        let mut view = View::new();
        for line in [
            r#"{"event":"plan","actions":["(move r a b)","(look r x b)"],"t":0}"#,
            r#"{"event":"action_started","index":0,"action":"(move r a b)","t":0}"#,
            r#"{"event":"action_done","index":0,"action":"(move r a b)","t":1}"#,
            r#"{"event":"action_started","index":1,"action":"(look r x b)","t":1}"#,
            r#"{"event":"observed","index":1,"action":"(look r x b)","observation":"(not (at x b))","t":2}"#,
            r#"{"event":"action_done","index":1,"action":"(look r x b)","t":2}"#,
            r#"{"event":"branch","observation":"(not (at x b))","probability":0.3,"actions":["(move r b c)","(get r x c)"],"t":2}"#,
        ] {
            view.log(&entry(line), None);
        }
        let snapshot = view.snapshot();
        let plan: Vec<&str> = snapshot["plan"]
            .as_array()
            .expect("plan")
            .iter()
            .filter_map(|a| a["action"].as_str())
            .collect();
        assert_eq!(
            plan,
            [
                "(move r a b)",
                "(look r x b)",
                "(move r b c)",
                "(get r x c)"
            ]
        );
        let texts = timeline_texts(&snapshot);
        assert!(texts.contains(&"observed (not (at x b))"), "{texts:?}");
        assert!(
            texts.contains(
                &"branch on (not (at x b)) (probability 0.3): (move r b c) → (get r x c)"
            ),
            "{texts:?}"
        );
    }

    #[test]
    fn the_world_peis_tuples_make_the_home_even_past_the_preview_length() {
        let mut view = View::new();
        let map = crate::home::tests::peis_home_map();
        assert!(map.chars().count() > PREVIEW);
        assert_eq!(view.snapshot()["home"], Json::Null);
        view.tuple(&tuple("world", "map", &map));
        view.tuple(&tuple("world", "robots.astrid.pose", "4.000 4.000 1.5708"));
        // The same keys of another PEIS are not the world's.
        view.tuple(&tuple("astrid", "robots.astrid.pose", "1.0 1.0 0.0"));
        let snapshot = view.snapshot();
        assert_eq!(snapshot["home"]["rooms"].as_array().map(Vec::len), Some(4));
        assert_eq!(snapshot["home"]["robots"][0]["room"], "entrance");
        assert!(
            snapshot["home"]["svg"]
                .as_str()
                .expect("svg")
                .contains(r#"data-robot="astrid" data-room="entrance""#)
        );
    }

    #[test]
    fn odd_log_entries_and_values_do_not_break_the_view() {
        let mut view = View::new();
        view.log(
            &entry(r#"{"event":"configuration","functionalities":[1, "x"],"cost":"?"}"#),
            None,
        );
        view.log(
            &entry(r#"{"event":"deployed","channels":["nonsense", "a → b"]}"#),
            None,
        );
        view.tuple(&tuple("p", "x", &"é".repeat(10_000)));
        let snapshot = view.snapshot();
        assert!(
            snapshot["tuples"][0]["value"]
                .as_str()
                .expect("value")
                .chars()
                .count()
                <= PREVIEW + 1
        );
        assert!(snapshot["svg"].as_str().expect("svg").contains("</svg>"));
    }
}
