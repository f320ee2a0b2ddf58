//! `ecology view`: the live web view of an ecology over Zenoh; and the same view of an in-process
//! run (`ecology demo --view`, `ecology run SCENARIO --view`).

use std::io::Write;
use std::net::SocketAddr;
use std::sync::Arc;

use anyhow::Context;
use clap::Args;
use ecology_tuples::{PeisId, TuplePattern, TupleSpace};
use ecology_view::Hub;

use crate::EXIT_OK;
use crate::network::{self, NetArgs};

/// Where the view is served (default 127.0.0.1:7070; port 0 picks a free one).
pub const DEFAULT_BIND: &str = "127.0.0.1:7070";

/// Arguments of `ecology view`.
#[derive(Debug, Args)]
pub struct ViewArgs {
    /// The address to serve the page on.
    #[arg(long, value_name = "ADDR", default_value = DEFAULT_BIND)]
    pub bind: SocketAddr,
    /// The PEIS name to join as (default: view-PID; with --keys, a member of the roster).
    #[arg(long, value_name = "PEIS")]
    pub name: Option<String>,
    #[command(flatten)]
    pub net: NetArgs,
}

/// A live view served from a thread of its own while the caller feeds its hub.
#[derive(Debug)]
pub struct Served {
    /// What the page shows.
    pub hub: Arc<Hub>,
    /// The page's address.
    pub url: String,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Served {
    /// Binds `addr` and serves the view from a new thread; prints the page's address.
    pub fn start(addr: SocketAddr) -> anyhow::Result<Served> {
        let listener = std::net::TcpListener::bind(addr)
            .with_context(|| format!("cannot serve the view on {addr}"))?;
        listener.set_nonblocking(true)?;
        let url = format!("http://{}/", listener.local_addr()?);
        let hub = Hub::new();
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let served = hub.clone();
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .context("starting the view's runtime")?;
        let thread = std::thread::Builder::new()
            .name("view".into())
            .spawn(move || {
                runtime.block_on(async move {
                    let Ok(listener) = tokio::net::TcpListener::from_std(listener) else {
                        return;
                    };
                    let stopped = async {
                        let _ = stopped.await;
                    };
                    if let Err(e) = ecology_view::serve(listener, served, stopped).await {
                        eprintln!("error: the view stopped: {e}");
                    }
                });
            })
            .context("starting the view's thread")?;
        eprintln!("view: {url}");
        Ok(Served {
            hub,
            url,
            stop: Some(stop),
            thread: Some(thread),
        })
    }

    /// Stops serving and waits for the server's thread.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Waits for SIGINT or SIGTERM, saying that the view stays up until then.
pub fn hold(served: &Served) -> anyhow::Result<()> {
    eprintln!("the view stays at {} until Ctrl-C", served.url);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the runtime")?;
    runtime.block_on(async { network::stop_signal().await });
    Ok(())
}

/// `ecology view`: joins the ecology, takes in every tuple and presence, and serves the page.
pub fn view(args: &ViewArgs) -> anyhow::Result<u8> {
    let name = match &args.name {
        Some(name) => PeisId::new(name),
        None => PeisId::new(&format!("view-{}", std::process::id())),
    };
    let name = match name {
        Ok(name) => name,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(crate::EXIT_BAD_INPUT);
        }
    };
    let served = Served::start(args.bind)?;
    let hub = served.hub.clone();
    let url = served.url.clone();
    let net = args.net.clone();
    let code = network::runtime()?.block_on(async move {
        let stop = network::stop_signal();
        let _reporter = network::report_on_sigusr1("view", None);
        let space = match network::join(name, &net).await {
            Ok(space) => space,
            Err(failure) => return Ok(crate::peis::join_failed(failure)),
        };
        let mut tuples = space.subscribe(TuplePattern::everything()).await?;
        let mut presence = space.subscribe_presence().await?;
        println!("view ready: {url}; {}", net.describe());
        let _ = std::io::stdout().flush();
        tokio::pin!(stop);
        loop {
            tokio::select! {
                which = &mut stop => {
                    println!("view: {which}: closing");
                    break;
                }
                Some(event) = tuples.next() => hub.update(|v| v.tuple(&event)),
                Some(event) = presence.next() => hub.update(|v| v.presence(&event)),
            }
        }
        drop((tuples, presence));
        space.close().await;
        Ok::<_, anyhow::Error>(EXIT_OK)
    });
    served.stop();
    code
}
