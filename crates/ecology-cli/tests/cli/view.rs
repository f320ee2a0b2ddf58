//! The live view in a real browser: `ecology demo --view` driven by headless Chromium over the
//! DevTools protocol, as a person would look at it (the paper's Section VIII, steps 5 and 6), with
//! the home's map beside the configuration.

use std::io::{BufRead, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{Value, json};

use crate::support::root;

/// Kills its child when dropped.
struct Guard(Child);

impl Drop for Guard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// A plain HTTP GET on 127.0.0.1, for the DevTools endpoint's list of pages.
fn http_get(port: u16, path: &str) -> Option<String> {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).ok()?;
    stream.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"
    )
    .ok()?;
    // Read until the server closes; what arrived counts even if the close is abrupt.
    let mut response = Vec::new();
    let mut buffer = [0u8; 16 * 1024];
    while let Ok(n) = stream.read(&mut buffer) {
        if n == 0 {
            break;
        }
        response.extend_from_slice(&buffer[..n]);
    }
    let response = String::from_utf8_lossy(&response);
    response
        .split_once("\r\n\r\n")
        .map(|(_, body)| body.to_owned())
}

/// One page of the browser, driven over its DevTools WebSocket.
struct Page {
    socket: tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>,
    next_id: u64,
}

impl Page {
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let message = json!({"id": id, "method": method, "params": params}).to_string();
        self.socket
            .send(tungstenite::Message::text(message))
            .expect("send to the browser");
        loop {
            let reply = self.socket.read().expect("read from the browser");
            if let tungstenite::Message::Text(text) = reply
                && let Ok(value) = serde_json::from_str::<Value>(text.as_str())
                && value["id"] == id
            {
                return value["result"].clone();
            }
        }
    }

    /// Evaluates `expression` in the page and returns its value.
    fn eval(&mut self, expression: &str) -> Value {
        self.call(
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true}),
        )["result"]["value"]
            .clone()
    }

    /// Polls `expression` until it is `true`; the page's text in the panic message otherwise.
    fn wait_until(&mut self, what: &str, expression: &str, patience: Duration) {
        let deadline = Instant::now() + patience;
        while Instant::now() < deadline {
            if self.eval(expression) == json!(true) {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!(
            "the page never showed {what}; it shows:\n{}",
            self.eval("document.body.innerText")
        );
    }
}

/// The browser: `CHROMIUM` or `chromium` (Debian's package, which `.ci/run` installs).
fn chromium() -> Option<String> {
    let browser = std::env::var("CHROMIUM").unwrap_or_else(|_| "chromium".into());
    let found = Command::new(&browser)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if found {
        Some(browser)
    } else {
        println!("skipped: no Chromium (`{browser}`) to look at the view with");
        None
    }
}

#[test]
fn the_view_shows_the_cameras_then_the_laser_after_the_tracking_system_fails() {
    let Some(browser) = chromium() else {
        return;
    };
    // The demo at 1.5x real time: the laser's configuration is up for about 3 s.
    let mut demo = Command::new(env!("CARGO_BIN_EXE_ecology"))
        .args(["demo", "--view", "--speed", "1.5", "--bind", "127.0.0.1:0"])
        .current_dir(root())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the demo");
    let stderr = demo.stderr.take().expect("piped stderr");
    let demo = Guard(demo);
    let (tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr)
            .lines()
            .map_while(Result::ok)
        {
            if tx.send(line).is_err() {
                return;
            }
        }
    });
    let url = loop {
        let line = lines
            .recv_timeout(Duration::from_secs(30))
            .expect("the demo prints where the view is");
        if let Some(url) = line.strip_prefix("view: ") {
            break url.to_owned();
        }
    };

    let port = free_port();
    let profile = std::env::temp_dir().join(format!("ecology-view-browser-{}", std::process::id()));
    let browser = Guard(
        Command::new(browser)
            .args([
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--no-first-run",
                "--window-size=1280,800",
                &format!("--remote-debugging-port={port}"),
                &format!("--user-data-dir={}", profile.display()),
                &url,
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromium"),
    );
    let deadline = Instant::now() + Duration::from_secs(30);
    let socket_url = loop {
        let body = http_get(port, "/json/list");
        let pages: Value = body
            .as_deref()
            .and_then(|body| serde_json::from_str(body).ok())
            .unwrap_or(Value::Null);
        let found = pages.as_array().and_then(|pages| {
            pages
                .iter()
                .find(|p| p["type"] == "page" && p["url"].as_str() == Some(url.as_str()))
                .and_then(|p| p["webSocketDebuggerUrl"].as_str().map(str::to_owned))
        });
        if let Some(found) = found {
            break found;
        }
        assert!(
            Instant::now() < deadline,
            "chromium never opened {url}; its pages: {body:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let (socket, _) = tungstenite::connect(socket_url.as_str()).expect("the DevTools socket");
    let mut page = Page { socket, next_id: 0 };
    let patience = Duration::from_secs(40);

    // The home beside the configuration: Astrid's marker names the room she is in; the page
    // records each room it shows her in, while the steps below are waited for.
    page.wait_until(
        "Astrid's marker in a room of the home",
        r#"(() => { const m = document.querySelector('#home g.robot[data-robot="astrid"]');
            if (m === null || !m.getAttribute("data-room")) return false;
            window.astridRooms = [m.getAttribute("data-room")];
            setInterval(() => {
              const m = document.querySelector('#home g.robot[data-robot="astrid"]');
              const room = m && m.getAttribute("data-room");
              if (room && window.astridRooms[window.astridRooms.length - 1] !== room)
                window.astridRooms.push(room);
            }, 50);
            return true; })()"#,
        patience,
    );

    // Step 5: the move to the bedroom on the ceiling cameras, cost 80.
    page.wait_until(
        "the cost-80 configuration with the ceiling cameras",
        r#"(() => { const c = document.getElementById("configuration");
            return c.textContent.includes("(navigate astrid bedroom): cost 80")
              && c.querySelector('g.functionality[data-component="hsm:ca1"]') !== null
              && c.querySelector('g.channel.remote') !== null; })()"#,
        patience,
    );
    // Step 6: the tracking system fails; the laser is switched on, cost 170, and the page says
    // who holds it (the executive, by its claim).
    page.wait_until(
        "the cost-170 configuration with the laser switched on, held by the executive, and hsm:tr1 failed",
        r#"(() => { const c = document.getElementById("configuration");
            const laser = document.querySelector('#peis tr[data-component="astrid:l1"]');
            return c.textContent.includes("(navigate astrid bedroom): cost 170")
              && c.querySelector('g.failed[data-component="hsm:tr1"]') !== null
              && c.querySelector('g.switched-on[data-component="astrid:l1"]') !== null
              && laser !== null && laser.children[2].textContent === "on"
              && laser.children[4].textContent === "executive"
              && document.getElementById("timeline").textContent.includes("FAILURE hsm:tr1"); })()"#,
        patience,
    );
    page.call(
        "Emulation.setDeviceMetricsOverride",
        json!({"width": 1280, "height": 800, "deviceScaleFactor": 1, "mobile": false}),
    );
    let shot = page.call("Page.captureScreenshot", json!({"format": "png"}));
    let png = base64::engine::general_purpose::STANDARD
        .decode(shot["data"].as_str().expect("a screenshot"))
        .expect("base64");
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
    let file = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("view-screenshot.png");
    std::fs::write(&file, &png).expect("save the screenshot");
    println!("screenshot: {} ({} bytes)", file.display(), png.len());

    // The run ends with the task done, Astrid in the bedroom, having been in another room first.
    page.wait_until(
        "the task done",
        r#"document.getElementById("status").textContent === "task done""#,
        patience,
    );
    page.wait_until(
        "Astrid's marker in the bedroom after another room",
        r#"(() => { const rooms = window.astridRooms;
            return new Set(rooms).size >= 2 && rooms[rooms.length - 1] === "bedroom"; })()"#,
        Duration::from_secs(5),
    );
    println!(
        "astrid's rooms: {}",
        page.eval("window.astridRooms.join(' → ')")
    );
    drop(page);
    drop(browser);
    drop(demo);
    let _ = std::fs::remove_dir_all(&profile);
}
