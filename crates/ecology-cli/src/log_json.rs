//! The executive's log as JSON lines: one object per event with `"t"` in
//! seconds and `"event"` named by [`LogEvent::name`], for `--json`, the
//! executive's `log` tuple and the live view. Built here, at the edge, so the
//! executive's types stay free of serialization.

use ecology_exec::{LogEntry, LogEvent};
use serde_json::json;

/// The entry as one line of JSON: `{"t": 12.5, "event": "failure", ...fields}`.
pub fn json_line(entry: &LogEntry) -> String {
    json_line_of(entry, None)
}

/// [`json_line`], with `"executive": NAME` when given: the lines of a run of
/// several tasks say whose executive logged each.
pub fn json_line_of(entry: &LogEntry, executive: Option<&str>) -> String {
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
            json!({ "peis": peis, "components": components, "unavailable": unavailable })
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
            "functionalities": functionalities,
            "alternatives": alternatives,
            "reconfiguration": reconfiguration,
        }),
        LogEvent::Deployed {
            switched_on,
            channels,
        } => json!({ "switched_on": switched_on, "channels": channels }),
        LogEvent::Running { switched_off } => json!({ "switched_off": switched_off }),
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
        } => {
            json!({ "switched_off": switched_off, "stopped": stopped, "unreachable": unreachable })
        }
        LogEvent::Reclaimed {
            peis,
            switched_off,
            stopped,
        } => json!({ "peis": peis, "switched_off": switched_off, "stopped": stopped }),
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
    object.to_string()
}
