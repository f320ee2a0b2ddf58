//! The tutorial's step 7 (docs/tutorial.md): the smart door written in Python
//! (examples/tutorial/door.py) joins the simulated world, rex and eye as processes, and the
//! executive configures the whole `(go-through rex door1 office)` with it: the door is wired to
//! rex's position, opens for rex, and the step is done.

use std::process::Command;

use nix::sys::signal::Signal;

use crate::processes::{costs, events, named, one_at_a_time, python, strings, task_args};
use crate::support::{Proc, free_endpoint, root};

#[test]
fn the_tutorials_door_in_python_opens_for_the_robot() {
    let python = python();
    let has_zenoh = Command::new(&python)
        .args(["-c", "import zenoh"])
        .status()
        .is_ok_and(|s| s.success());
    if !has_zenoh {
        println!(
            "skipped: no Python with the eclipse-zenoh package at `{python}` to run examples/tutorial/door.py (scripts/test sets up .venv)"
        );
        return;
    }
    let _one = one_at_a_time();
    let scenario = root()
        .join("examples/tutorial/office.toml")
        .display()
        .to_string();
    let world = free_endpoint();
    let _world = Proc::start("world", &["world", &scenario, "--listen", &world]).ready();
    let peis = |name: &str| {
        let listen = free_endpoint();
        Proc::start(
            name,
            &[
                "peis",
                &scenario,
                "--name",
                name,
                "--listen",
                &listen,
                "--connect",
                &world,
            ],
        )
        .ready()
    };
    let _rex = peis("rex");
    let _eye = peis("eye");
    let mut command = Command::new(&python);
    command.arg(root().join("examples/tutorial/door.py")).args([
        "--listen",
        &free_endpoint(),
        "--connect",
        &world,
    ]);
    let mut door = Proc::spawn("door", command);
    door.wait_for("ready", |l| l == "ready");
    let listen = free_endpoint();
    let task = Proc::start(
        "executive",
        &task_args(
            "examples/tutorial/door.eco",
            "examples/tutorial/door.plan",
            "world,rex,eye,door1",
            &["--listen", &listen, "--connect", &world],
        ),
    );
    let (code, lines) = task.finish();
    let all = events(&lines);
    assert_eq!(code, Some(0), "{all:#?}");
    // The camera's way, with the door (the tutorial's 100 less its channel costs).
    assert_eq!(costs(&all), [(85, false)], "{all:#?}");
    let deployed = named(&all, "deployed");
    assert!(
        strings(&deployed[0]["channels"]).contains(&"rex:s1 → door1:m1 (position rex)".to_string()),
        "{all:#?}"
    );
    // The step has a postcondition on the door: it is done only once the door reported `done`.
    assert_eq!(named(&all, "action_done").len(), 1, "{all:#?}");
    door.signal(Signal::SIGTERM);
    let (code, _) = door.finish();
    assert_eq!(code, Some(0));
}
