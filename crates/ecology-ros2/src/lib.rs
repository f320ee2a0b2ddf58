//! ROS 2 lifecycle nodes as Ecology components.
//!
//! A PEIS file may say that a component is a ROS 2 node ([`NodeSpec`]): its name, which ROS
//! parameters take which argument of the functionality instance, and the topic and message type
//! of each input and output. `ecology peis` then runs one [`Agent`] (a Python process on the
//! stock `rclpy`) and gives each such component a [`Ros2Component`] body: switching it on with
//! params configures and activates the node, putting it back deactivates and cleans it up, its
//! lifecycle state becomes the component's status, and its topics are bridged to and from the
//! component's tuples. docs/ros2.md is the user's guide.

mod agent;
mod component;
mod spec;

pub use agent::{AGENT_SOURCE, Agent, AgentError, AgentEvent, PYTHON_VARIABLE, default_python};
pub use component::{Ros2Component, announce_topics, topic_key};
pub use spec::{Feed, MESSAGES, NodeSpec, Port};
