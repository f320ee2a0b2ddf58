//! The executive's log as JSON, both ways: one object per entry with `"t"` in seconds,
//! `"event"` named by [`LogEvent::name`] and the event's fields, for `ecology task --json`,
//! `ecology demo --json`, the executive's `log` tuple, and `ecology view` reading that tuple.
//! Components, functionalities and channels travel as the timeline's text of them
//! (`astrid:l1`, `(laser astrid l1) on astrid:l1`, `astrid:l1 → astrid:tc1 (range-scan astrid)`),
//! which [`decode`] reads back into values.

use std::time::Duration;

use ecology_exec::{
    LogChannel, LogComponent, LogEntry, LogEvent, LogFunctionality, LogUnavailable,
};
use serde_json::{Value as Json, json};

/// An entry read back from JSON, with the executive that logged it when the line says.
#[derive(Debug, Clone, PartialEq)]
pub struct Decoded {
    /// The entry.
    pub entry: LogEntry,
    /// Whose executive logged it (`"executive"`), in a run of several tasks.
    pub executive: Option<String>,
}

/// The entry as one line of JSON: `{"t": 12.5, "event": "failure", ...fields}`, with
/// `"executive": NAME` when given (the lines of a run of several tasks say whose executive
/// logged each).
pub fn json_line(entry: &LogEntry, executive: Option<&str>) -> String {
    encode(entry, executive).to_string()
}

/// Each item's text, for a JSON array of strings.
fn texts<T: ToString>(items: &[T]) -> Vec<String> {
    items.iter().map(ToString::to_string).collect()
}

/// The entry as a JSON object; see [`json_line`].
pub fn encode(entry: &LogEntry, executive: Option<&str>) -> Json {
    let mut object = match &entry.event {
        LogEvent::Plan { actions, branches } => {
            json!({ "actions": actions, "branches": branches })
        }
        LogEvent::Replanned {
            failed,
            actions,
            branches,
        } => {
            json!({ "failed": failed, "actions": actions, "branches": branches })
        }
        LogEvent::ActionStarted { index, action } => {
            json!({ "index": index, "action": action })
        }
        LogEvent::StateAcquired {
            peis,
            components,
            unavailable,
            ..
        } => {
            json!({ "peis": peis, "components": components, "unavailable": texts(unavailable) })
        }
        LogEvent::Configuration {
            goal,
            cost,
            optimal,
            functionalities,
            alternatives,
            reconfiguration,
            micros,
        } => json!({
            "micros": micros,
            "goal": goal,
            "cost": cost,
            "optimal": optimal,
            "functionalities": texts(functionalities),
            "alternatives": alternatives,
            "reconfiguration": reconfiguration,
        }),
        LogEvent::Deployed {
            switched_on,
            channels,
        } => json!({ "switched_on": texts(switched_on), "channels": texts(channels) }),
        LogEvent::Running { switched_off } => json!({ "switched_off": texts(switched_off) }),
        LogEvent::Failure {
            peis,
            component,
            cause,
        } => {
            json!({ "peis": peis, "component": component, "cause": cause })
        }
        LogEvent::Reconfiguration { excluded } => json!({ "excluded": excluded }),
        LogEvent::PeisJoined { peis }
        | LogEvent::PeisLeft { peis }
        | LogEvent::PeisRestarted { peis } => json!({ "peis": peis }),
        LogEvent::RemoteSetFailed { owner, key, reason } => {
            json!({ "owner": owner, "key": key, "reason": reason })
        }
        LogEvent::RemoteSetRetried { owner, key } => json!({ "owner": owner, "key": key }),
        LogEvent::Held {
            peis,
            component,
            holders,
        } => json!({ "peis": peis, "component": component, "holders": holders }),
        LogEvent::Released {
            switched_off,
            stopped,
            unreachable,
        } => json!({
            "switched_off": texts(switched_off),
            "stopped": texts(stopped),
            "unreachable": texts(unreachable),
        }),
        LogEvent::Reclaimed {
            peis,
            switched_off,
            stopped,
        } => json!({
            "peis": peis,
            "switched_off": texts(switched_off),
            "stopped": texts(stopped),
        }),
        LogEvent::EcologyLost {
            gone,
            present,
            waiting,
        } => json!({ "gone": gone, "present": present, "waiting_s": waiting.as_secs_f64() }),
        LogEvent::EcologyBack { back, missing } => json!({ "back": back, "missing": missing }),
        LogEvent::AwaitingReturn { gone, waiting } => {
            json!({ "gone": gone, "waiting_s": waiting.as_secs_f64() })
        }
        LogEvent::WaitingLonger {
            peis,
            component,
            waited_for,
            waiting,
        } => json!({
            "peis": peis,
            "component": component,
            "waited_for": waited_for,
            "waiting_s": waiting.as_secs_f64(),
        }),
        LogEvent::ActionDone { index, action } => json!({ "index": index, "action": action }),
        LogEvent::ActionFailed {
            index,
            action,
            reason,
        } => {
            json!({ "index": index, "action": action, "reason": reason })
        }
        LogEvent::Observed {
            index,
            action,
            observation,
        } => json!({ "index": index, "action": action, "observation": observation }),
        LogEvent::Branch {
            observation,
            probability,
            actions,
        } => json!({ "observation": observation, "probability": probability, "actions": actions }),
        LogEvent::TaskDone => json!({}),
        LogEvent::TaskFailed { reason } => json!({ "reason": reason }),
    };
    if let Some(fields) = object.as_object_mut() {
        fields.insert("t".to_string(), json!(entry.t.as_secs_f64()));
        fields.insert("event".to_string(), json!(entry.event.name()));
        if let Some(executive) = executive {
            fields.insert("executive".to_string(), json!(executive));
        }
    }
    object
}

/// A line of JSON read back into an entry; `None` when it is not JSON or not a log entry.
pub fn decode_line(line: &str) -> Option<Decoded> {
    decode(&serde_json::from_str(line).ok()?)
}

/// A JSON object read back into an entry; `None` when it names no known event. It reads what
/// another process wrote, so it is lenient: a field missing or of another type reads as empty
/// (0, `""`, `[]`), and an item of a list that cannot be read is left out.
pub fn decode(object: &Json) -> Option<Decoded> {
    let fields = Fields(object.as_object()?);
    let event = decode_event(&fields, fields.text("event").as_str())?;
    let t = duration(fields.0.get("t"));
    let executive = fields.0.get("executive").and_then(Json::as_str);
    Some(Decoded {
        entry: LogEntry { t, event },
        executive: executive.map(str::to_owned),
    })
}

fn decode_event(fields: &Fields<'_>, name: &str) -> Option<LogEvent> {
    let f = fields;
    Some(match name {
        "plan" => LogEvent::Plan {
            actions: f.texts("actions"),
            branches: f.texts("branches"),
        },
        "replan" => LogEvent::Replanned {
            failed: f.text("failed"),
            actions: f.texts("actions"),
            branches: f.texts("branches"),
        },
        "action_started" => LogEvent::ActionStarted {
            index: f.index(),
            action: f.text("action"),
        },
        "state_acquired" => LogEvent::StateAcquired {
            peis: f.count("peis"),
            components: f.count("components"),
            unavailable: f.read("unavailable", unavailable),
            micros: 0,
        },
        "configuration" => LogEvent::Configuration {
            goal: f.text("goal"),
            cost: f.number("cost"),
            optimal: f.flag("optimal"),
            functionalities: f.read("functionalities", functionality),
            alternatives: f.list("alternatives").filter_map(Json::as_u64).collect(),
            reconfiguration: f.flag("reconfiguration"),
            micros: f.number("micros"),
        },
        "deployed" => LogEvent::Deployed {
            switched_on: f.read("switched_on", component),
            channels: f.read("channels", channel),
        },
        "running" => LogEvent::Running {
            switched_off: f.read("switched_off", component),
        },
        "failure" => LogEvent::Failure {
            peis: f.text("peis"),
            component: f.text("component"),
            cause: f.text("cause"),
        },
        "reconfiguration" => LogEvent::Reconfiguration {
            excluded: f.texts("excluded"),
        },
        "peis_joined" => LogEvent::PeisJoined {
            peis: f.text("peis"),
        },
        "peis_left" => LogEvent::PeisLeft {
            peis: f.text("peis"),
        },
        "peis_restarted" => LogEvent::PeisRestarted {
            peis: f.text("peis"),
        },
        "remote_set_failed" => LogEvent::RemoteSetFailed {
            owner: f.text("owner"),
            key: f.text("key"),
            reason: f.text("reason"),
        },
        "remote_set_retried" => LogEvent::RemoteSetRetried {
            owner: f.text("owner"),
            key: f.text("key"),
        },
        "held" => LogEvent::Held {
            peis: f.text("peis"),
            component: f.text("component"),
            holders: f.texts("holders"),
        },
        "released" => LogEvent::Released {
            switched_off: f.read("switched_off", component),
            stopped: f.read("stopped", component),
            unreachable: f.read("unreachable", component),
        },
        "reclaimed" => LogEvent::Reclaimed {
            peis: f.text("peis"),
            switched_off: f.read("switched_off", component),
            stopped: f.read("stopped", component),
        },
        "ecology_lost" => LogEvent::EcologyLost {
            gone: f.texts("gone"),
            present: f.count("present"),
            waiting: f.waiting(),
        },
        "ecology_back" => LogEvent::EcologyBack {
            back: f.texts("back"),
            missing: f.texts("missing"),
        },
        "awaiting_return" => LogEvent::AwaitingReturn {
            gone: f.texts("gone"),
            waiting: f.waiting(),
        },
        "waiting_longer" => LogEvent::WaitingLonger {
            peis: f.text("peis"),
            component: f.text("component"),
            waited_for: f.text("waited_for"),
            waiting: f.waiting(),
        },
        "action_done" => LogEvent::ActionDone {
            index: f.index(),
            action: f.text("action"),
        },
        "action_failed" => LogEvent::ActionFailed {
            index: f.index(),
            action: f.text("action"),
            reason: f.text("reason"),
        },
        "observed" => LogEvent::Observed {
            index: f.index(),
            action: f.text("action"),
            observation: f.text("observation"),
        },
        "branch" => LogEvent::Branch {
            observation: f.text("observation"),
            probability: f.0.get("probability").and_then(Json::as_f64).unwrap_or(0.0),
            actions: f.texts("actions"),
        },
        "task_done" => LogEvent::TaskDone,
        "task_failed" => LogEvent::TaskFailed {
            reason: f.text("reason"),
        },
        _ => return None,
    })
}

/// The fields of an entry's object, read leniently.
struct Fields<'a>(&'a serde_json::Map<String, Json>);

impl Fields<'_> {
    fn text(&self, field: &str) -> String {
        self.0
            .get(field)
            .and_then(Json::as_str)
            .unwrap_or("")
            .to_owned()
    }

    fn list(&self, field: &str) -> impl Iterator<Item = &Json> {
        self.0
            .get(field)
            .and_then(Json::as_array)
            .into_iter()
            .flatten()
    }

    fn texts(&self, field: &str) -> Vec<String> {
        self.read(field, |text| Some(text.to_owned()))
    }

    /// The strings of list `field` that `parse` reads.
    fn read<T>(&self, field: &str, parse: impl Fn(&str) -> Option<T>) -> Vec<T> {
        self.list(field)
            .filter_map(Json::as_str)
            .filter_map(parse)
            .collect()
    }

    fn number(&self, field: &str) -> u64 {
        self.0.get(field).and_then(Json::as_u64).unwrap_or(0)
    }

    fn count(&self, field: &str) -> usize {
        usize::try_from(self.number(field)).unwrap_or(usize::MAX)
    }

    fn index(&self) -> usize {
        self.count("index")
    }

    fn flag(&self, field: &str) -> bool {
        self.0.get(field).and_then(Json::as_bool).unwrap_or(false)
    }

    fn waiting(&self) -> Duration {
        duration(self.0.get("waiting_s"))
    }
}

/// Seconds as a duration; 0 when they are not a number of seconds a duration can hold.
fn duration(seconds: Option<&Json>) -> Duration {
    seconds
        .and_then(Json::as_f64)
        .and_then(|s| Duration::try_from_secs_f64(s).ok())
        .unwrap_or_default()
}

/// `astrid:l1`.
fn component(text: &str) -> Option<LogComponent> {
    let (peis, component) = text.split_once(':')?;
    Some(LogComponent::new(peis, component))
}

/// `(navigation astrid tc1 entrance) on astrid:tc1`: the last ` on ` ends the call, since
/// names hold no spaces.
fn functionality(text: &str) -> Option<LogFunctionality> {
    let (call, at) = text.rsplit_once(" on ")?;
    Some(LogFunctionality {
        call: call.to_owned(),
        component: component(at)?,
    })
}

/// `hsm:ca1 → hsm:tr1 (image hsm)`.
fn channel(text: &str) -> Option<LogChannel> {
    let (from, rest) = text.split_once(" → ")?;
    let (to, info) = rest.split_once(' ')?;
    Some(LogChannel {
        from: component(from)?,
        to: component(to)?,
        info: info.into(),
    })
}

/// `hsm:tr1 reports error (no images)`.
fn unavailable(text: &str) -> Option<LogUnavailable> {
    let (at, cause) = text.split_once(" reports error (")?;
    Some(LogUnavailable {
        component: component(at)?,
        cause: cause.strip_suffix(')').unwrap_or(cause).to_owned(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(seconds: f64, event: LogEvent) -> LogEntry {
        LogEntry {
            t: Duration::from_secs_f64(seconds),
            event,
        }
    }

    /// Every kind of event, encoded and decoded, comes back the same, and its line is the
    /// shape the docs and consumers rely on.
    #[test]
    fn entries_go_to_json_and_back() {
        let l1 = LogComponent::new("astrid", "l1");
        let tc1 = LogComponent::new("astrid", "tc1");
        let events = vec![
            LogEvent::Plan {
                actions: vec!["(move astrid a b)".into()],
                branches: vec!["(at x b)".into()],
            },
            LogEvent::StateAcquired {
                peis: 3,
                components: 12,
                unavailable: vec![LogUnavailable {
                    component: LogComponent::new("hsm", "tr1"),
                    cause: "no images (camera ca1)".into(),
                }],
                micros: 0,
            },
            LogEvent::Configuration {
                goal: "(navigate astrid b)".into(),
                cost: 170,
                optimal: true,
                functionalities: vec![LogFunctionality {
                    call: "(laser astrid l1)".into(),
                    component: l1.clone(),
                }],
                alternatives: vec![170, 180],
                reconfiguration: true,
                micros: 12,
            },
            LogEvent::Deployed {
                switched_on: vec![l1.clone()],
                channels: vec![LogChannel {
                    from: l1.clone(),
                    to: tc1.clone(),
                    info: "(range-scan astrid)".into(),
                }],
            },
            LogEvent::Released {
                switched_off: vec![l1.clone()],
                stopped: vec![tc1.clone()],
                unreachable: Vec::new(),
            },
            LogEvent::AwaitingReturn {
                gone: vec!["hsm".into()],
                waiting: Duration::from_secs(30),
            },
            LogEvent::Branch {
                observation: "(not (at x b))".into(),
                probability: 0.3,
                actions: Vec::new(),
            },
            LogEvent::TaskDone,
        ];
        for event in events {
            let logged = entry(15.5, event);
            let line = json_line(&logged, Some("exec-bob"));
            let back = decode_line(&line).expect(&line);
            assert_eq!(back.entry, logged, "{line}");
            assert_eq!(back.executive.as_deref(), Some("exec-bob"));
        }
        let line = json_line(
            &entry(
                1.0,
                LogEvent::Deployed {
                    switched_on: vec![l1.clone()],
                    channels: vec![LogChannel {
                        from: l1,
                        to: tc1,
                        info: "(range-scan astrid)".into(),
                    }],
                },
            ),
            None,
        );
        assert_eq!(
            line,
            r#"{"channels":["astrid:l1 → astrid:tc1 (range-scan astrid)"],"event":"deployed","switched_on":["astrid:l1"],"t":1.0}"#
        );
    }

    #[test]
    fn odd_json_reads_leniently_or_not_at_all() {
        assert_eq!(decode_line("[1,2,3]"), None);
        assert_eq!(decode_line(r#"{"event":"no such event"}"#), None);
        let odd = decode_line(
            r#"{"event":"deployed","channels":["nonsense","a → b",1],"switched_on":["x"]}"#,
        )
        .expect("a deployment");
        assert_eq!(
            odd.entry.event,
            LogEvent::Deployed {
                switched_on: Vec::new(),
                channels: Vec::new()
            }
        );
        assert_eq!(odd.entry.t, Duration::ZERO);
    }
}
