//! The web server of the live view: the page, the state as JSON, and server-sent events that push
//! the state whenever it changes. Everything it serves is inside the binary.

use std::convert::Infallible;
use std::future::Future;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use axum::Router;
use axum::extract::State;
use axum::http::header;
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse};
use axum::routing::get;
use futures_util::stream::Stream;
use tokio::sync::watch;

use crate::state::View;

/// The page: HTML, CSS and script in one file, no outside resources.
const PAGE: &str = include_str!("page.html");

/// How often at most the state is pushed to a page while things change.
const PUSH_EVERY: Duration = Duration::from_millis(100);

/// The view shared between whatever feeds it and the server.
#[derive(Debug)]
pub struct Hub {
    view: Mutex<View>,
    changed: watch::Sender<u64>,
}

impl Hub {
    /// A hub with an empty view.
    pub fn new() -> Arc<Self> {
        Arc::new(Self {
            view: Mutex::new(View::new()),
            changed: watch::Sender::new(0),
        })
    }

    /// Changes the view with `change` and tells every page.
    pub fn update(&self, change: impl FnOnce(&mut View)) {
        let version = {
            let mut view = lock(&self.view);
            change(&mut view);
            view.version()
        };
        self.changed.send_replace(version);
    }

    /// The view's current state as JSON.
    pub fn snapshot(&self) -> serde_json::Value {
        lock(&self.view).snapshot()
    }
}

fn lock(m: &Mutex<View>) -> MutexGuard<'_, View> {
    // Every update leaves the view consistent, so a poisoned lock is still usable.
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Serves the view on `listener` until `shutdown` completes.
pub async fn serve(
    listener: tokio::net::TcpListener,
    hub: Arc<Hub>,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let app = Router::new()
        .route("/", get(|| async { Html(PAGE) }))
        .route("/state", get(state))
        .route("/events", get(events))
        .route("/configuration.svg", get(svg))
        .with_state(hub);
    axum::serve(listener, app)
        .with_graceful_shutdown(shutdown)
        .await
}

async fn state(State(hub): State<Arc<Hub>>) -> impl IntoResponse {
    (
        [(header::CONTENT_TYPE, "application/json")],
        hub.snapshot().to_string(),
    )
}

async fn svg(State(hub): State<Arc<Hub>>) -> impl IntoResponse {
    let svg = hub.snapshot()["svg"]
        .as_str()
        .map(str::to_owned)
        .unwrap_or_else(|| crate::svg::Drawing::default().svg());
    ([(header::CONTENT_TYPE, "image/svg+xml")], svg)
}

/// The state now, then again after every change (at most every [`PUSH_EVERY`]).
async fn events(State(hub): State<Arc<Hub>>) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let changes = hub.changed.subscribe();
    let stream = futures_util::stream::unfold(
        (hub, changes, true),
        |(hub, mut changes, first)| async move {
            if !first {
                changes.changed().await.ok()?;
                tokio::time::sleep(PUSH_EVERY).await;
            }
            changes.borrow_and_update();
            let event = Event::default()
                .event("state")
                .data(hub.snapshot().to_string());
            Some((Ok(event), (hub, changes, false)))
        },
    );
    Sse::new(stream).keep_alive(KeepAlive::default())
}
