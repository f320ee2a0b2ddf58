//! Tests of the PEIS host and the component context on the in-process tuple
//! space, in virtual time.

use std::sync::Arc;
use std::time::Duration;

use ecology_tuples::{
    Clock, InProcessPeis, InProcessSpace, Key, PeisId, PeisOptions, Tuple, TupleEvent,
    TuplePattern, TupleSpace, Value, VirtualClock,
};

use crate::{Component, ComponentError, ComponentSpec, Context, HostOptions, run_host};

struct Fixture {
    clock: VirtualClock,
    space: InProcessSpace,
    host: tokio::task::JoinHandle<Result<(), crate::HostError>>,
    stop: tokio::sync::oneshot::Sender<()>,
    other: InProcessPeis,
}

fn key(k: &str) -> Key {
    Key::new(k).expect("key")
}

async fn start(components: Vec<ComponentSpec<InProcessPeis>>) -> Fixture {
    let clock = VirtualClock::default();
    let shared: Arc<dyn Clock> = Arc::new(clock.clone());
    let space = InProcessSpace::new(shared.clone());
    let robot = space
        .join(PeisId::new("robot").expect("name"), PeisOptions::default())
        .expect("joins");
    let other = space
        .join(PeisId::new("other").expect("name"), PeisOptions::default())
        .expect("joins");
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let host = tokio::spawn(run_host(robot, shared, components, async {
        let _ = stopped.await;
    }));
    Fixture {
        clock,
        space,
        host,
        stop,
        other,
    }
}

/// How far virtual time moves in one step.
const STEP: Duration = Duration::from_millis(10);

impl Fixture {
    /// Joins PEIS `name` to the fixture's ecology.
    fn join(&self, name: &str) -> InProcessPeis {
        self.space
            .join(PeisId::new(name).expect("name"), PeisOptions::default())
            .expect("joins")
    }

    /// Lets virtual time pass a `STEP` at a time until robot's `k` reads `want`, failing once
    /// `within` of virtual time has passed; returns that tuple. The tests run on tokio's paused
    /// clock (`start_paused`), which moves on (ending the step's sleep) only when no task can run:
    /// so each step comes once the host has handled everything the last one set off.
    async fn wait_for(&self, k: &str, want: &str, within: Duration) -> Tuple {
        let mut changes = self
            .other
            .subscribe(TuplePattern::exact(
                PeisId::new("robot").expect("name"),
                &key(k),
            ))
            .await
            .expect("subscribe");
        let mut passed = Duration::ZERO;
        loop {
            tokio::select! {
                biased;
                event = changes.next() => match event {
                    Some(TupleEvent::Changed(t)) if t.text().ok() == Some(want) => return t,
                    Some(_) => {}
                    None => panic!("the subscription to {k} ended"),
                },
                () = tokio::time::sleep(STEP) => {
                    assert!(
                        passed < within,
                        "{k} did not read {want:?} within {within:?} of virtual time; it reads {:?}",
                        self.get(k).await
                    );
                    self.clock.advance(STEP);
                    passed += STEP;
                }
            }
        }
    }

    /// Gives `l1` params and switches it on; returns once it runs (its start-up is 1 s).
    async fn run_l1(&self) {
        self.set("l1.params", "(laser robot l1)").await;
        self.set("components.l1.reqState", "on").await;
        self.wait_for("l1.status", "running", Duration::from_millis(1100))
            .await;
    }

    async fn get(&self, k: &str) -> Option<String> {
        let t: Option<Tuple> = self
            .other
            .get(PeisId::new("robot").expect("name"), key(k))
            .await
            .expect("get");
        t.map(|t| t.text().expect("text").to_string())
    }

    async fn set(&self, k: &str, v: &str) -> Tuple {
        self.other
            .set_remote(PeisId::new("robot").expect("name"), key(k), Value::text(v))
            .await
            .expect("remote set")
    }

    async fn stop(self) {
        let _ = self.stop.send(());
        self.host.await.expect("host task").expect("clean shutdown");
        self.space.shutdown().await;
    }
}

fn spec(
    name: &str,
    on: bool,
    body: Arc<dyn Component<InProcessPeis>>,
) -> ComponentSpec<InProcessPeis> {
    ComponentSpec {
        name: name.to_string(),
        kind: "laser".to_string(),
        cost: 100,
        on,
        startup: Duration::from_secs(1),
        covers: Vec::new(),
        body,
    }
}

/// Runs until cancelled, publishing its params' arguments.
fn echo() -> Arc<dyn Component<InProcessPeis>> {
    Arc::new(|ctx: Context<InProcessPeis>| async move {
        ctx.status("running", None).await?;
        loop {
            ctx.output("range-scan", Value::text(ctx.args().join(" ")))
                .await?;
            ctx.sleep(Duration::from_millis(100)).await;
        }
    })
}

#[tokio::test(start_paused = true)]
async fn the_init_component_publishes_and_starts_components() {
    let f = start(vec![spec("l1", false, echo())]).await;
    f.wait_for("components.l1.type", "laser", Duration::from_millis(10))
        .await;
    f.wait_for("components.l1.cost", "100", Duration::from_millis(100))
        .await;
    f.wait_for("components.l1.currState", "off", Duration::from_millis(100))
        .await;
    f.wait_for("l1.status", "idle", Duration::from_millis(100))
        .await;

    f.set("l1.params", "(laser robot l1)").await;
    let asked = f.set("components.l1.reqState", "on").await;
    let on = f
        .wait_for("components.l1.currState", "on", Duration::from_millis(1100))
        .await;
    let took = on.ts_write.saturating_duration_since(asked.ts_write);
    assert!(
        took >= Duration::from_secs(1),
        "on {took:?} after the request, before its start-up delay"
    );
    f.wait_for("l1.status", "running", Duration::from_millis(100))
        .await;
    f.wait_for("l1.out.range-scan", "robot l1", Duration::from_millis(100))
        .await;

    // New params restart the body with them.
    f.set("l1.params", "(laser robot l2)").await;
    f.wait_for("l1.out.range-scan", "robot l2", Duration::from_millis(200))
        .await;

    f.set("components.l1.reqState", "off").await;
    f.wait_for("components.l1.currState", "off", Duration::from_millis(100))
        .await;
    f.wait_for("l1.status", "idle", Duration::from_millis(100))
        .await;
    f.stop().await;
}

/// An output goes out only while someone reads it: nothing is written while nobody subscribes,
/// the next value once someone does, and the value is deleted once they go, so a later reader
/// is never handed an old one. Status goes out whether or not anyone reads it.
#[tokio::test(start_paused = true)]
async fn an_output_goes_out_only_while_someone_reads_it() {
    let counter: Arc<dyn Component<InProcessPeis>> =
        Arc::new(|ctx: Context<InProcessPeis>| async move {
            ctx.status("running", None).await?;
            for n in 0.. {
                let read = ctx.is_read("range-scan")?;
                let written = ctx.output("range-scan", Value::text(n.to_string())).await?;
                assert_eq!(written.is_some(), read);
                ctx.sleep(Duration::from_millis(100)).await;
            }
            Ok(())
        });
    let f = start(vec![spec("l1", false, counter)]).await;
    f.run_l1().await;
    f.clock.advance(Duration::from_secs(1));
    tokio::time::sleep(STEP).await;
    assert_eq!(f.get("l1.out.range-scan").await, None, "nobody reads it");

    let robot = PeisId::new("robot").expect("name");
    let mut reader = f
        .other
        .subscribe(TuplePattern::exact(
            robot.clone(),
            &key("l1.out.range-scan"),
        ))
        .await
        .expect("subscribe");
    let first = loop {
        tokio::select! {
            biased;
            event = reader.next() => match event {
                Some(TupleEvent::Changed(t)) => break t,
                other => panic!("unexpected {other:?}"),
            },
            () = tokio::time::sleep(STEP) => f.clock.advance(STEP),
        }
    };
    let n: u64 = first.text().expect("text").parse().expect("a count");
    assert!(
        n >= 1,
        "the first value read is a new one, not the first taken: {n}"
    );
    drop(reader);
    for _ in 0..20 {
        f.clock.advance(STEP);
        tokio::time::sleep(STEP).await;
    }
    assert_eq!(
        f.get("l1.out.range-scan").await,
        None,
        "once unread, it is deleted"
    );
    assert_eq!(f.get("l1.status").await.as_deref(), Some("running"));
    f.stop().await;
}

/// An output kept back because nobody read it goes out the moment a reader comes, while the body
/// waits on `readers_came`: the reader does not wait for the body's next output.
#[tokio::test(start_paused = true)]
async fn a_kept_back_output_goes_out_when_a_reader_comes() {
    let slow: Arc<dyn Component<InProcessPeis>> =
        Arc::new(|ctx: Context<InProcessPeis>| async move {
            ctx.status("running", None).await?;
            for n in 0.. {
                ctx.output("range-scan", Value::text(n.to_string())).await?;
                let deadline = ctx.clock().now().saturating_add(Duration::from_secs(60));
                loop {
                    tokio::select! {
                        () = ctx.clock().sleep_until(deadline) => break,
                        came = ctx.readers_came() => came?,
                    }
                }
            }
            Ok(())
        });
    let f = start(vec![spec("l1", false, slow)]).await;
    f.run_l1().await;
    assert_eq!(f.get("l1.out.range-scan").await, None, "nobody reads it");
    let asked = f.clock.now();
    let got = f
        .wait_for("l1.out.range-scan", "0", Duration::from_millis(10))
        .await;
    assert!(
        got.ts_write.saturating_duration_since(asked) < Duration::from_secs(1),
        "the value kept back went out as the reader came, not a minute later"
    );
    f.stop().await;
}

#[tokio::test(start_paused = true)]
async fn a_failing_or_panicking_body_is_reported_and_the_peis_goes_on() {
    let failing: Arc<dyn Component<InProcessPeis>> =
        Arc::new(|ctx: Context<InProcessPeis>| async move {
            ctx.status("running", None).await?;
            ctx.sleep(Duration::from_millis(200)).await;
            Err::<(), _>(ComponentError::Fault("lens cracked".into()))
        });
    let panicking: Arc<dyn Component<InProcessPeis>> =
        Arc::new(|_ctx: Context<InProcessPeis>| async move {
            let empty: Vec<u8> = Vec::new();
            if empty.is_empty() {
                panic!("a bug in the component");
            }
            Ok::<(), ComponentError>(())
        });
    let f = start(vec![
        spec("a", true, failing),
        spec("b", true, panicking),
        spec("c", true, echo()),
    ])
    .await;
    f.set("a.params", "(x)").await;
    f.set("b.params", "(y)").await;
    f.set("c.params", "(laser robot c)").await;
    f.wait_for("a.status", "error", Duration::from_millis(500))
        .await;
    f.wait_for("a.cause", "lens cracked", Duration::from_millis(100))
        .await;
    f.wait_for("b.status", "error", Duration::from_millis(100))
        .await;
    assert!(
        f.get("b.cause")
            .await
            .is_some_and(|c| c.contains("panicked"))
    );
    assert_eq!(
        f.get("c.status").await.as_deref(),
        Some("running"),
        "the others go on"
    );
    f.stop().await;
}

#[tokio::test(start_paused = true)]
async fn switching_on_again_restarts_a_body_that_failed() {
    let attempts = Arc::new(std::sync::atomic::AtomicU32::new(0));
    let counted = attempts.clone();
    let fails_once: Arc<dyn Component<InProcessPeis>> =
        Arc::new(move |ctx: Context<InProcessPeis>| {
            let attempt = counted.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            async move {
                if attempt == 0 {
                    return Err(ComponentError::Fault("lens fogged".into()));
                }
                ctx.status("running", None).await?;
                std::future::pending::<()>().await;
                Ok(())
            }
        });
    let f = start(vec![spec("a", true, fails_once)]).await;
    f.set("a.params", "(x)").await;
    f.wait_for("a.status", "error", Duration::from_millis(100))
        .await;
    // It is on, so `on` used to change nothing and the component stayed dead.
    f.set("components.a.reqState", "on").await;
    f.wait_for("a.status", "running", Duration::from_millis(100))
        .await;
    assert_eq!(attempts.load(std::sync::atomic::Ordering::Relaxed), 2);
    f.stop().await;
}

#[tokio::test(start_paused = true)]
async fn inputs_follow_meta_tuples_and_report_what_is_missing() {
    let consumer: Arc<dyn Component<InProcessPeis>> =
        Arc::new(|ctx: Context<InProcessPeis>| async move {
            let mut inputs = ctx.inputs(&["range-scan"]).await?;
            loop {
                inputs.poll();
                let missing = inputs.missing(Duration::from_millis(300));
                if missing.is_empty() {
                    let seen = inputs
                        .latest("range-scan")
                        .map(|t| t.text().unwrap_or("").to_string());
                    ctx.status("running", seen.as_deref()).await?;
                } else {
                    ctx.status("waiting", Some(&missing.join(" "))).await?;
                }
                ctx.sleep(Duration::from_millis(100)).await;
            }
        });
    let f = start(vec![spec("l1", true, echo()), spec("s1", true, consumer)]).await;
    f.set("s1.params", "(scan-matching robot s1)").await;
    f.wait_for("s1.status", "waiting", Duration::from_millis(200))
        .await;
    f.wait_for("s1.cause", "range-scan", Duration::from_millis(100))
        .await;
    // Wire the input to the laser's output, as the deployer does.
    f.set("l1.params", "(laser robot l1)").await;
    f.set("s1.mi-range-scan", "(meta robot l1.out.range-scan)")
        .await;
    f.wait_for("s1.status", "running", Duration::from_millis(300))
        .await;
    f.wait_for("s1.cause", "robot l1", Duration::from_millis(100))
        .await;
    // The producer stops: the input goes stale.
    f.set("components.l1.reqState", "off").await;
    f.wait_for("s1.status", "waiting", Duration::from_millis(600))
        .await;
    f.stop().await;
}

#[tokio::test(start_paused = true)]
async fn params_name_a_functionality_and_its_arguments() {
    let f = start(Vec::new()).await;
    let clock: Arc<dyn Clock> = Arc::new(f.clock.clone());
    let context = |params: &str| {
        Context::new(
            f.other.clone(),
            "s1".to_string(),
            params.to_string(),
            clock.clone(),
        )
    };
    let full = context("(scan-matching robot s1)");
    assert_eq!(full.functionality(), "scan-matching");
    assert_eq!(full.args(), ["robot", "s1"]);
    let bare = context("(laser)");
    assert_eq!(bare.functionality(), "laser");
    assert!(bare.args().is_empty());
    f.stop().await;
}

/// The dead man's switch: what a PEIS asked for is put back once that PEIS has been gone for
/// `release_after`, whether it left or vanished; one that comes back in time keeps it, and what
/// the owner set itself (no creator) is never undone.
#[tokio::test(start_paused = true)]
async fn a_host_puts_back_what_a_gone_peis_asked_for() {
    let f = start(vec![
        spec("l1", false, echo()),
        spec("l2", false, echo()),
        spec("l3", false, echo()),
    ])
    .await;
    let robot = PeisId::new("robot").expect("name");
    let executive = f.join("executive");
    for c in ["l1", "l2"] {
        let params = executive
            .set_remote(
                robot.clone(),
                key(&format!("{c}.params")),
                Value::text("(laser robot l1)"),
            )
            .await
            .expect("params");
        assert_eq!(
            params.creator,
            Some(PeisId::new("executive").expect("name"))
        );
        executive
            .set_remote(
                robot.clone(),
                key(&format!("components.{c}.reqState")),
                Value::text("on"),
            )
            .await
            .expect("on");
    }
    // l3 is the other PEIS's, which stays.
    f.set("l3.params", "(laser robot l3)").await;
    f.set("components.l3.reqState", "on").await;
    for c in ["l1", "l2", "l3"] {
        f.wait_for(
            &format!("{c}.status"),
            "running",
            Duration::from_millis(1200),
        )
        .await;
    }

    // Vanished: seen gone a lease (PeisOptions' default) after, released one second later.
    let lease = PeisOptions::default().lease;
    let gone_at = f.clock.now();
    executive.vanish();
    let off = f
        .wait_for(
            "components.l1.currState",
            "off",
            lease + Duration::from_millis(1200),
        )
        .await;
    let after = off.ts_write.saturating_duration_since(gone_at);
    assert!(
        after >= lease + HostOptions::default().release_after,
        "released {after:?} after the executive vanished, before its lease and grace ran out"
    );
    let req = f
        .wait_for("components.l1.reqState", "off", Duration::ZERO)
        .await;
    assert_eq!(req.creator, None, "the host wrote it itself");
    f.wait_for("components.l2.currState", "off", Duration::from_millis(100))
        .await;
    for c in ["l1", "l2"] {
        assert_eq!(f.get(&format!("{c}.params")).await.as_deref(), Some(""));
        f.wait_for(&format!("{c}.status"), "idle", Duration::from_millis(100))
            .await;
    }
    assert_eq!(
        f.get("components.l3.currState").await.as_deref(),
        Some("on")
    );
    assert_eq!(f.get("l3.status").await.as_deref(), Some("running"));

    // A PEIS that leaves and comes back within the grace keeps what it asked for.
    let executive = f.join("executive");
    executive
        .set_remote(
            robot.clone(),
            key("components.l1.reqState"),
            Value::text("on"),
        )
        .await
        .expect("on");
    f.wait_for("components.l1.currState", "on", Duration::from_millis(1200))
        .await;
    executive.leave();
    f.clock.advance(Duration::from_millis(500));
    let _back = f.join("executive");
    let mut passed = Duration::ZERO;
    while passed < Duration::from_secs(3) {
        tokio::time::sleep(STEP).await;
        f.clock.advance(STEP);
        passed += STEP;
    }
    assert_eq!(
        f.get("components.l1.currState").await.as_deref(),
        Some("on")
    );
    f.stop().await;
}

/// A PEIS that asked for something and left before the host could watch its presence is not
/// seen present, and what it asked for is put back `release_after` after the host saw the request.
#[tokio::test(start_paused = true)]
async fn a_host_puts_back_what_a_peis_gone_before_it_was_watched_asked_for() {
    let f = start(vec![spec("l1", false, echo())]).await;
    let robot = PeisId::new("robot").expect("name");
    let executive = f.join("executive");
    let asked_at = f.clock.now();
    for (k, v) in [
        ("l1.params", "(laser robot l1)"),
        ("components.l1.reqState", "on"),
    ] {
        executive
            .set_remote(robot.clone(), key(k), Value::text(v))
            .await
            .expect("asks");
    }
    // Gone before the host has run once since the requests.
    executive.leave();
    let off = f
        .wait_for("components.l1.reqState", "off", Duration::from_millis(2500))
        .await;
    assert_eq!(off.creator, None, "the host wrote it itself");
    let after = off.ts_write.saturating_duration_since(asked_at);
    assert!(
        after >= HostOptions::default().release_after,
        "released {after:?} after the request, before the grace ran out"
    );
    assert_eq!(f.get("l1.params").await.as_deref(), Some(""));
    f.stop().await;
}

/// A body that finished (`done`) leaves its component `done` until its params are cleared, which
/// leaves it `idle` as when a running body is stopped.
#[tokio::test(start_paused = true)]
async fn clearing_the_params_of_a_finished_component_leaves_it_idle() {
    let finishes: Arc<dyn Component<InProcessPeis>> =
        Arc::new(|ctx: Context<InProcessPeis>| async move {
            ctx.status("done", None).await?;
            Ok(())
        });
    let f = start(vec![spec("g1", true, finishes)]).await;
    f.set("g1.params", "(gripper robot g1 newspaper)").await;
    f.wait_for("g1.status", "done", Duration::from_millis(200))
        .await;
    f.set("g1.params", "").await;
    f.wait_for("g1.status", "idle", Duration::from_millis(200))
        .await;
    f.stop().await;
}

/// The contract's answers, in one run: an input's wiring (`C.mi-INFO`) is the PEIS's own tuple,
/// which neither new params nor switching off and on touch, so a restarted body follows it again;
/// and writing the same params again restarts the body (`initializing` once more).
#[tokio::test(start_paused = true)]
async fn wiring_survives_new_params_and_switching_and_the_same_params_restart() {
    let starts = Arc::new(std::sync::atomic::AtomicU32::new(0));
    let counted = starts.clone();
    let consumer: Arc<dyn Component<InProcessPeis>> =
        Arc::new(move |ctx: Context<InProcessPeis>| {
            let run = counted.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
            async move {
                let mut inputs = ctx.inputs(&["range-scan"]).await?;
                loop {
                    inputs.poll();
                    match inputs.latest("range-scan") {
                        Some(t) if inputs.missing(Duration::from_millis(300)).is_empty() => {
                            let seen = format!("run {run}: {}", t.text().unwrap_or(""));
                            ctx.status("running", Some(&seen)).await?;
                        }
                        _ => ctx.status("waiting", Some("range-scan")).await?,
                    }
                    ctx.sleep(Duration::from_millis(100)).await;
                }
            }
        });
    let f = start(vec![spec("l1", true, echo()), spec("s1", true, consumer)]).await;
    f.set("l1.params", "(laser robot l1)").await;
    f.set("s1.mi-range-scan", "(meta robot l1.out.range-scan)")
        .await;
    f.set("s1.params", "(scan-matching robot s1)").await;
    f.wait_for("s1.cause", "run 1: robot l1", Duration::from_millis(500))
        .await;
    // New params: a new run, still wired.
    f.set("s1.params", "(scan-matching robot s1 again)").await;
    f.wait_for("s1.cause", "run 2: robot l1", Duration::from_millis(500))
        .await;
    // The same params again: restarted all the same.
    f.set("s1.params", "(scan-matching robot s1 again)").await;
    f.wait_for("s1.status", "initializing", Duration::from_millis(100))
        .await;
    f.wait_for("s1.cause", "run 3: robot l1", Duration::from_millis(500))
        .await;
    // Off and on again (a new task would do this): the wiring is still there. The one who
    // switched it off held it alone, so its params went with it; given again, it runs them.
    f.set("components.s1.reqState", "off").await;
    f.wait_for("s1.status", "idle", Duration::from_millis(100))
        .await;
    assert_eq!(f.get("s1.params").await.as_deref(), Some(""));
    f.set("components.s1.reqState", "on").await;
    f.set("s1.params", "(scan-matching robot s1 again)").await;
    f.wait_for("s1.cause", "run 4: robot l1", Duration::from_secs(2))
        .await;
    assert_eq!(
        f.get("s1.mi-range-scan").await.as_deref(),
        Some("(meta robot l1.out.range-scan)")
    );
    f.stop().await;
}
