//! ROS 2 lifecycle nodes as components: the example nodes of `examples/ros2/ecology_nodes.py`,
//! real `rclpy` processes on Fast DDS, configured by the executive through the ROS 2 agent of
//! `ecology peis` (scenarios/peis-home-ros2.toml).
//!
//! ROS 2 comes from PyPI (`ros-rclpy`, `ros-rmw-fastrtps-cpp` and the message packages), which
//! `scripts/test` installs into `.venv`. Each run takes a ROS domain of its own, so that nodes of
//! another run on the machine are not seen.

use std::process::Command;
use std::time::{Duration, Instant};

use nix::sys::signal::Signal;

use crate::processes::{costs, events, imports, named, process_slot_alone, python, strings};
use crate::support::{Fixture, Proc, TO_BEDROOM, Variant, event, free_endpoint, is_event, task_on};

const SCENARIO: &str = "scenarios/peis-home-ros2.toml";

/// The Python with `rclpy`: `ECOLOGY_ROS2_PYTHON`, else the one the Python tests use. `None`
/// (the test says it is skipped) only where there is no Python at all.
fn ros_python() -> Option<String> {
    let python = std::env::var("ECOLOGY_ROS2_PYTHON").unwrap_or_else(|_| python());
    if Command::new(&python).arg("--version").output().is_err() {
        println!("skipped: no Python at `{python}` to run the ROS 2 nodes of examples/ros2");
        return None;
    }
    let has_rclpy = imports(&python, "rclpy, lifecycle_msgs, geometry_msgs, sensor_msgs");
    assert!(
        has_rclpy,
        "{python} has no rclpy: run scripts/test, which installs ROS 2 from PyPI into .venv \
         (or name a Python with ROS 2 in ECOLOGY_ROS2_PYTHON)"
    );
    Some(python)
}

/// A ROS domain for this run alone: 101 to 230 (Fast DDS takes up to 232 on Linux), apart from
/// the 0 to 100 that people and the examples' own checks use.
fn ros_domain() -> String {
    (101 + std::process::id() % 130).to_string()
}

/// `python examples/ros2/ecology_nodes.py KIND --name NAME --namespace NS`, once it spins.
fn node(python: &str, domain: &str, kind: &str, namespace: &str, name: &str) -> Proc {
    let mut command = Command::new(python);
    command
        .args(["-u", "examples/ros2/ecology_nodes.py", kind])
        .args(["--name", name, "--namespace", namespace])
        .env("ROS_DOMAIN_ID", domain);
    let mut proc = Proc::spawn(&format!("{namespace}-{name}"), command);
    proc.wait_for("ready", |l| l.trim() == "ready");
    proc
}

/// The lifecycle state of each of `nodes` (`unconfigured`, `inactive`, `active`, `finalized`,
/// `gone`), asked by one process.
fn lifecycle_states(python: &str, domain: &str, nodes: &[&str]) -> Vec<String> {
    let out = Command::new(python)
        .arg("examples/ros2/lifecycle_state.py")
        .args(nodes)
        .args(["--timeout", "5"])
        .env("ROS_DOMAIN_ID", domain)
        .current_dir(crate::support::root())
        .output()
        .expect("runs lifecycle_state.py");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| l.trim().to_string())
        .collect()
}

/// `ecology ARGS…` with the ROS 2 environment, its stderr read with its stdout.
fn ecology_ros(name: &str, python: &str, domain: &str, args: &[&str]) -> Proc {
    let mut command = Command::new("sh");
    command
        .args([
            "-c",
            r#"exec "$0" "$@" 2>&1"#,
            env!("CARGO_BIN_EXE_ecology"),
        ])
        .args(args)
        .env("ECOLOGY_ROS2_PYTHON", python)
        .env("ROS_DOMAIN_ID", domain);
    Proc::spawn(name, command)
}

// The paper's move to the bedroom with the tracker, Astrid's self-localisation and her navigation
// as ROS 2 lifecycle nodes: configured at 80 (the ceiling tracker), the tracker's process killed
// mid-move, reconfigured to the laser at 170, the task done by the ROS 2 navigation; afterwards
// no node Ecology activated is active.
#[test]
fn ros2_nodes_are_configured_reconfigured_and_put_back() {
    let Some(python) = ros_python() else { return };
    let _slot = process_slot_alone();
    let domain = ros_domain();
    let tracker = node(&python, &domain, "tracker", "hsm", "tr1");
    let _self_loc = node(&python, &domain, "self_loc", "astrid", "s1");
    let _navigation = node(&python, &domain, "navigation", "astrid", "tc1");
    assert_eq!(
        lifecycle_states(&python, &domain, &["/hsm/tr1", "/astrid/s1", "/astrid/tc1"]),
        ["unconfigured", "unconfigured", "unconfigured"]
    );

    let world_endpoint = free_endpoint();
    let _world = ecology_ros(
        "world",
        &python,
        &domain,
        &["world", SCENARIO, "--listen", &world_endpoint],
    )
    .ready();
    let peis = |name: &str| {
        let listen = free_endpoint();
        let args = [
            "peis",
            SCENARIO,
            "--name",
            name,
            "--listen",
            &listen,
            "--connect",
            &world_endpoint,
        ];
        ecology_ros(name, &python, &domain, &args).ready()
    };
    let mut astrid = peis("astrid");
    let hsm = peis("hsm");

    let fixture = Fixture::new("ros2", &[TO_BEDROOM], Variant::Paper);
    let mut task = task_on(&world_endpoint, None, &fixture, &[]);
    task.wait_for("running", |l| is_event(l, "running"));
    // Mid-move, the tracker's process is killed.
    tracker.signal(Signal::SIGKILL);
    task.wait_for("the reconfiguration", |l| {
        is_event(l, "configuration") && event(l)["reconfiguration"] == true
    });
    // Still moving, on the laser: Ecology's nodes are active; each channel between two nodes
    // stays in DDS, relayed by Astrid's agent.
    assert_eq!(
        lifecycle_states(&python, &domain, &["/astrid/s1", "/astrid/tc1"]),
        ["active", "active"]
    );
    for relay in [
        "astrid:s1 reads global-pos from /hsm/tr1/global_pos, relayed in DDS",
        "astrid:tc1 reads position from /astrid/s1/position, relayed in DDS",
    ] {
        if !astrid.seen.iter().any(|l| l.text.contains(relay)) {
            astrid.wait_for(relay, |l| l.contains(relay));
        }
    }
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    assert_eq!(costs(&all), [(80, false), (170, true)], "{all:#?}");
    let failures = named(&all, "failure");
    assert!(
        failures.iter().any(|f| f["component"] == "tr1"
            && f["cause"]
                .as_str()
                .is_some_and(|c| c.contains("ROS 2 node /hsm/tr1 does not answer"))),
        "{failures:#?}"
    );
    let deployed = named(&all, "deployed");
    assert_eq!(strings(&deployed[1]["switched_on"]), ["astrid:l1"]);
    assert_eq!(
        all.last().map(|e| e["event"].clone()),
        Some("task_done".into())
    );

    // Released by the executive, the nodes are deactivated and cleaned up by the agent.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let states = lifecycle_states(&python, &domain, &["/astrid/s1", "/astrid/tc1"]);
        if states == ["unconfigured", "unconfigured"] {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "after the task, s1 and tc1 are {states:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }

    // Stopped, the PEIS puts back what it still ran and its agent exits with it.
    hsm.signal(Signal::SIGINT);
    astrid.signal(Signal::SIGINT);
    astrid.wait_for("its goodbye", |l| l.contains("presence withdrawn"));
    let (code, _) = astrid.finish();
    assert_eq!(code, Some(0));
}

// The agent alone against the example nodes: every request of its protocol, bad lines, a node
// that never comes, a refused parameter, a node deactivated by hand, a killed node, the text
// forms of the messages both ways, and quitting with every node put back.
#[test]
fn the_ros2_agent_passes_its_own_check() {
    let Some(python) = ros_python() else { return };
    let _slot = process_slot_alone();
    let out = Command::new(&python)
        .args(["examples/ros2/check_agent.py", "--domain", &ros_domain()])
        .current_dir(crate::support::root())
        .output()
        .expect("runs check_agent.py");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && stdout.contains("check_agent: ok"),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

// A PEIS file's `ros2` tables are checked before anything starts, and a ROS 2 scenario does not
// run in simulated time.
#[test]
fn ros2_components_are_checked_and_need_processes() {
    let out = Command::new(env!("CARGO_BIN_EXE_ecology"))
        .args(["run", SCENARIO])
        .current_dir(crate::support::root())
        .output()
        .expect("runs");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("component astrid:s1 is a ROS 2 node: ROS 2 nodes run in real time"),
        "{stderr}"
    );

    let dir = std::env::temp_dir().join(format!("ecology-ros2-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    for (ros2, why) in [
        (
            r#"node = "tr1""#,
            "node `tr1` must be a fully qualified ROS 2 node name",
        ),
        (
            r#"node = "/hsm/tr1"
outputs = [{ info = "global-pos", topic = "~/p", type = "nav_msgs/msg/Odometry" }]"#,
            "no conversion for message type `nav_msgs/msg/Odometry`",
        ),
        (
            r#"node = "/hsm/tr1"
inputs = [{ info = "image", topic = "~/bad topic", type = "std_msgs/msg/String" }]"#,
            "`~/bad topic` is not a ROS 2 topic name",
        ),
        (
            r#"node = "/hsm/tr1"
arguments = { target = 0 }"#,
            "arguments count from 1",
        ),
        (
            r#"node = "/hsm/tr1"
qos = "best""#,
            "unknown field `qos`",
        ),
    ] {
        let file = dir.join("bad.toml");
        std::fs::write(
            &file,
            format!(
                "[[peis]]\nname = \"hsm\"\n[[peis.components]]\nid = \"tr1\"\ntype = \"tr-sys\"\ncost = 20\n\
                 [peis.components.ros2]\n{ros2}\n"
            ),
        )
        .expect("write");
        let out = Command::new(env!("CARGO_BIN_EXE_ecology"))
            .args(["peis", file.to_str().expect("utf-8"), "--name", "hsm"])
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{ros2}: {stderr}");
        assert!(stderr.contains(why), "{ros2}: {why:?} not in {stderr}");
        assert!(
            stderr.contains("bad.toml:"),
            "{ros2}: no position in {stderr}"
        );
    }

    // A Python without rclpy: a clear error before the PEIS joins, saying what to install.
    let file = dir.join("good.toml");
    std::fs::write(
        &file,
        "[[peis]]\nname = \"hsm\"\n[[peis.components]]\nid = \"tr1\"\ntype = \"tr-sys\"\ncost = 20\n\
         [peis.components.ros2]\nnode = \"/hsm/tr1\"\n",
    )
    .expect("write");
    let fake = dir.join("python-without-rclpy");
    std::fs::write(
        &fake,
        "#!/bin/sh\necho \"ModuleNotFoundError: No module named 'rclpy'\" >&2\nexit 1\n",
    )
    .expect("write");
    std::fs::set_permissions(&fake, std::os::unix::fs::PermissionsExt::from_mode(0o755))
        .expect("chmod");
    let listen = free_endpoint();
    let out = Command::new(env!("CARGO_BIN_EXE_ecology"))
        .args(["peis", file.to_str().expect("utf-8"), "--name", "hsm"])
        .args(["--listen", &listen])
        .env("ECOLOGY_ROS2_PYTHON", &fake)
        .output()
        .expect("runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("the ROS 2 agent on"), "{stderr}");
    assert!(stderr.contains("pip install ros-rclpy"), "{stderr}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("hsm ready"));
    let _ = std::fs::remove_dir_all(&dir);
}
