//! What a PEIS file says of a component that is a ROS 2 lifecycle node: the node, which ROS
//! parameters take which argument of the functionality instance, and for each input and output
//! its information, topic and message type.
//!
//! Names follow ROS 2's rules: a node's fully qualified name is `/NAMESPACE/NAME` (tokens of
//! letters, digits and `_`, not starting with a digit); a topic is absolute (`/hsm/tr1/image`),
//! relative to the node's namespace (`image` → `/hsm/image`) or private to the node (`~/image` →
//! `/hsm/tr1/image`). [`NodeSpec::resolved`] checks every name and makes every topic absolute.

use ecology_tuples::{Key, PeisId};

/// The message types the agent converts to and from the text of Ecology's tuples, with the text
/// form of each.
pub const MESSAGES: &[(&str, &str)] = &[
    ("geometry_msgs/msg/Pose2D", "X Y THETA"),
    (
        "geometry_msgs/msg/PoseStamped",
        "X Y THETA (yaw from the quaternion)",
    ),
    ("geometry_msgs/msg/Twist", "V W (linear.x, angular.z)"),
    (
        "sensor_msgs/msg/LaserScan",
        "R1 R2 … (N rays around the robot from its heading)",
    ),
    ("std_msgs/msg/String", "the text as it is"),
    ("std_msgs/msg/Float64", "a number"),
];

/// A component that is a ROS 2 lifecycle node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeSpec {
    /// The node's fully qualified name, such as `/hsm/tr1`.
    pub node: String,
    /// ROS parameters set from the functionality instance before the node is configured: the
    /// parameter's name and which argument (1 for the first after the functionality's name).
    pub arguments: Vec<(String, usize)>,
    /// The node's inputs: each information the executive may wire to it.
    pub inputs: Vec<Port>,
    /// The node's outputs, published as the component's `C.out.INFO` tuples.
    pub outputs: Vec<Port>,
    /// Tuples published to the node on a topic of their own whatever the configuration (such as
    /// the world's map).
    pub feeds: Vec<Feed>,
    /// A `std_msgs/msg/String` topic on which the node reports `running`, `waiting CAUSE`,
    /// `done` or `error CAUSE`; without it the component is `running` while the node is active.
    pub status_topic: Option<String>,
}

/// One input or output of a node.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Port {
    /// The information's name in the domain, such as `global-pos`.
    pub info: String,
    /// The topic.
    pub topic: String,
    /// The message type, one of [`MESSAGES`].
    pub message: String,
}

/// A tuple fed to a node on a topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Feed {
    /// The tuple, `OWNER:KEY` (such as `world:map`).
    pub tuple: String,
    /// The topic.
    pub topic: String,
    /// The message type, one of [`MESSAGES`].
    pub message: String,
}

impl Feed {
    /// The tuple's owner and key.
    pub fn owner_and_key(&self) -> Result<(PeisId, Key), String> {
        let (owner, key) = self
            .tuple
            .split_once(':')
            .ok_or_else(|| format!("feed `{}` must name a tuple as OWNER:KEY", self.tuple))?;
        let owner = PeisId::new(owner).map_err(|e| format!("feed `{}`: {e}", self.tuple))?;
        let key = Key::new(key).map_err(|e| format!("feed `{}`: {e}", self.tuple))?;
        Ok((owner, key))
    }
}

/// Whether `token` is a ROS 2 name token: letters, digits and `_`, not starting with a digit.
fn is_token(token: &str) -> bool {
    !token.is_empty()
        && !token.starts_with(|c: char| c.is_ascii_digit())
        && token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Whether `name` is `/TOKEN/…/TOKEN`.
fn is_absolute(name: &str) -> bool {
    name.strip_prefix('/')
        .is_some_and(|rest| rest.split('/').all(is_token))
}

impl NodeSpec {
    /// The node's namespace (`/hsm` for `/hsm/tr1`, `/` for `/tr1`).
    pub fn namespace(&self) -> &str {
        match self.node.rfind('/') {
            Some(0) | None => "/",
            Some(i) => &self.node[..i],
        }
    }

    /// `topic` made absolute against this node.
    fn resolve(&self, topic: &str) -> Result<String, String> {
        let absolute = if let Some(private) = topic.strip_prefix("~/") {
            format!("{}/{private}", self.node)
        } else if topic.starts_with('/') {
            topic.to_string()
        } else {
            match self.namespace() {
                "/" => format!("/{topic}"),
                ns => format!("{ns}/{topic}"),
            }
        };
        if is_absolute(&absolute) {
            Ok(absolute)
        } else {
            Err(format!(
                "`{topic}` is not a ROS 2 topic name (tokens of letters, digits and _, separated by /; \
                 absolute /a/b, relative a/b, or private ~/a)"
            ))
        }
    }

    /// This spec with every name checked and every topic absolute; the error says what is wrong.
    pub fn resolved(&self) -> Result<NodeSpec, String> {
        if !is_absolute(&self.node) {
            return Err(format!(
                "node `{}` must be a fully qualified ROS 2 node name, such as /hsm/tr1",
                self.node
            ));
        }
        let message = |m: &str| {
            if MESSAGES.iter().any(|(known, _)| *known == m) {
                Ok(m.to_string())
            } else {
                let known: Vec<&str> = MESSAGES.iter().map(|(k, _)| *k).collect();
                Err(format!(
                    "no conversion for message type `{m}` (known: {})",
                    known.join(", ")
                ))
            }
        };
        let port = |p: &Port| -> Result<Port, String> {
            if Key::new(&p.info).is_err() || p.info.contains('.') {
                return Err(format!("`{}` cannot name an information", p.info));
            }
            Ok(Port {
                info: p.info.clone(),
                topic: self.resolve(&p.topic)?,
                message: message(&p.message)?,
            })
        };
        let mut seen = std::collections::BTreeSet::new();
        for (name, position) in &self.arguments {
            if !is_token(name) && !name.split('.').all(is_token) {
                return Err(format!("`{name}` cannot name a ROS 2 parameter"));
            }
            if *position == 0 {
                return Err(format!(
                    "parameter {name}: arguments count from 1 (the first after the functionality's name)"
                ));
            }
            if !seen.insert(name) {
                return Err(format!("parameter {name} is given twice"));
            }
        }
        let inputs = self
            .inputs
            .iter()
            .map(port)
            .collect::<Result<Vec<_>, _>>()?;
        let outputs = self
            .outputs
            .iter()
            .map(port)
            .collect::<Result<Vec<_>, _>>()?;
        for (kind, ports) in [("input", &inputs), ("output", &outputs)] {
            for (i, p) in ports.iter().enumerate() {
                if ports[..i].iter().any(|q| q.info == p.info) {
                    return Err(format!("{kind} {} is given twice", p.info));
                }
            }
        }
        let feeds = self
            .feeds
            .iter()
            .map(|f| {
                f.owner_and_key()?;
                Ok(Feed {
                    tuple: f.tuple.clone(),
                    topic: self.resolve(&f.topic)?,
                    message: message(&f.message)?,
                })
            })
            .collect::<Result<Vec<_>, String>>()?;
        let status_topic = self
            .status_topic
            .as_deref()
            .map(|t| self.resolve(t))
            .transpose()?;
        Ok(NodeSpec {
            node: self.node.clone(),
            arguments: self.arguments.clone(),
            inputs,
            outputs,
            feeds,
            status_topic,
        })
    }

    /// The ROS parameters for the functionality instance whose arguments are `args`: each named
    /// parameter with its argument; an error names a parameter whose argument is missing.
    pub fn parameters(&self, args: &[&str]) -> Result<Vec<(String, String)>, String> {
        self.arguments
            .iter()
            .map(|(name, position)| {
                args.get(position - 1)
                    .map(|a| (name.clone(), (*a).to_string()))
                    .ok_or_else(|| {
                        format!(
                            "ROS parameter {name} takes argument {position}, but the params have {}",
                            args.len()
                        )
                    })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tracker() -> NodeSpec {
        NodeSpec {
            node: "/hsm/tr1".into(),
            arguments: vec![("target".into(), 3)],
            inputs: vec![Port {
                info: "image".into(),
                topic: "~/image".into(),
                message: "std_msgs/msg/String".into(),
            }],
            outputs: vec![Port {
                info: "global-pos".into(),
                topic: "global_pos".into(),
                message: "geometry_msgs/msg/Pose2D".into(),
            }],
            feeds: vec![Feed {
                tuple: "world:map".into(),
                topic: "/map".into(),
                message: "std_msgs/msg/String".into(),
            }],
            status_topic: Some("~/ecology_status".into()),
        }
    }

    #[test]
    fn topics_resolve_as_ros_2_resolves_them() {
        let spec = tracker().resolved().expect("valid");
        assert_eq!(spec.inputs[0].topic, "/hsm/tr1/image");
        assert_eq!(spec.outputs[0].topic, "/hsm/global_pos");
        assert_eq!(spec.feeds[0].topic, "/map");
        assert_eq!(
            spec.status_topic.as_deref(),
            Some("/hsm/tr1/ecology_status")
        );
        let top = NodeSpec {
            node: "/tr1".into(),
            ..tracker()
        };
        assert_eq!(
            top.resolved().expect("valid").outputs[0].topic,
            "/global_pos"
        );
    }

    #[test]
    fn bad_names_and_types_are_refused_with_what_is_wrong() {
        let cases: Vec<(NodeSpec, &str)> = vec![
            (
                NodeSpec {
                    node: "hsm/tr1".into(),
                    ..tracker()
                },
                "fully qualified",
            ),
            (
                NodeSpec {
                    node: "/hsm/1tr".into(),
                    ..tracker()
                },
                "fully qualified",
            ),
            (
                NodeSpec {
                    status_topic: Some("~/bad topic".into()),
                    ..tracker()
                },
                "not a ROS 2 topic name",
            ),
            (
                NodeSpec {
                    outputs: vec![Port {
                        info: "global-pos".into(),
                        topic: "x".into(),
                        message: "nav_msgs/msg/Odometry".into(),
                    }],
                    ..tracker()
                },
                "no conversion for message type `nav_msgs/msg/Odometry`",
            ),
            (
                NodeSpec {
                    arguments: vec![("target".into(), 0)],
                    ..tracker()
                },
                "count from 1",
            ),
            (
                NodeSpec {
                    feeds: vec![Feed {
                        tuple: "map".into(),
                        topic: "m".into(),
                        message: "std_msgs/msg/String".into(),
                    }],
                    ..tracker()
                },
                "OWNER:KEY",
            ),
        ];
        for (spec, expected) in cases {
            let error = spec.resolved().expect_err("invalid");
            assert!(error.contains(expected), "{error:?} lacks {expected:?}");
        }
    }

    #[test]
    fn parameters_take_their_arguments() {
        let spec = tracker();
        assert_eq!(
            spec.parameters(&["hsm", "tr1", "astrid"]),
            Ok(vec![("target".to_string(), "astrid".to_string())])
        );
        let missing = spec.parameters(&["hsm"]).expect_err("too few");
        assert!(missing.contains("takes argument 3"), "{missing}");
    }
}
