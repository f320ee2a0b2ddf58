//! The tutorial's step 7 (docs/tutorial.md): the smart door written in Python
//! (examples/tutorial/door.py) joins the simulated world, rex and eye as processes, and the
//! executive configures the whole `(go-through rex door1 office)` with it: the door is wired to
//! rex's position, opens for rex, and the step is done.

use crate::processes::{WithPython, costs, imports, named, process_slot, python, strings};

#[test]
fn the_tutorials_door_in_python_opens_for_the_robot() {
    let python = python();
    let has_zenoh = imports(&python, "zenoh");
    if !has_zenoh {
        println!(
            "skipped: no Python with the eclipse-zenoh package at `{python}` to run examples/tutorial/door.py (scripts/test sets up .venv)"
        );
        return;
    }
    let _slot = process_slot();
    let ecology = WithPython::start(
        &python,
        "examples/tutorial/office.toml",
        &["rex", "eye"],
        "examples/tutorial/door.py",
        "door",
    );
    let (code, all) = ecology.task(
        "examples/tutorial/door.eco",
        "examples/tutorial/door.plan",
        "world,rex,eye,door1",
    );
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
    ecology.stop_component();
}
