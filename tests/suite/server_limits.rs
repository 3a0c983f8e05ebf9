//! `raypick serve` against slow clients and large requests (issue 11 item 8): servers started
//! in-process on ephemeral loopback ports (127.0.0.1 only), spoken to with raw TCP so that the
//! tests can hold connections idle, stop half-way through headers or bodies, and see when the
//! server closes them. Checks that idle, half-header (even trickled) and half-body connections
//! are closed after the configured (shortened) timeouts, that normal picks still answer while
//! 200 idle connections are held, that connections beyond the cap wait for a free slot, and that
//! a request over the memory budget gets 503 while the next normal request answers 200, and that
//! an error sentence quotes at most 60 characters of a megabyte-long field name or value, that
//! the requests hyper refuses itself (400, 414, 431) get their sentence too, that a slow but
//! steady reader of a large answer gets all of it, that a body not read whole ends the
//! connection with `connection: close` said, as does any answer that leaves the body unread
//! (403, 404, 503); and,
//! for `raypick serve` in a child process, that work over `--max-memory` gets 503 too and a
//! `--memory-budget` over `--max-memory` is refused at start. Every
//! loop is bounded; the whole file runs in a few seconds.

use raypick::check::synthetic::example_scene;
use raypick::server::ServerConfig;
use raypick::{Backend, BuildOptions, BuiltScene};
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Starts a server over the built-in example scene on an ephemeral loopback port; returns its
/// address. The server runs on its own runtime thread until the test binary exits.
fn start(config: ServerConfig) -> SocketAddr {
    let built = Arc::new(
        BuiltScene::new(example_scene(), &BuildOptions::default()).expect("example builds"),
    );
    crate::common::serve(built, Backend::Cpu, config)
}

/// A connection with a read timeout of `wait`.
fn connect(addr: SocketAddr, wait: Duration) -> TcpStream {
    let stream = TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(wait)).expect("read timeout");
    stream
}

/// One request on a fresh connection (`Connection: close`): the status and the body.
fn request(addr: SocketAddr, method: &str, path: &str, body: &str) -> (u16, String) {
    let mut stream = connect(addr, Duration::from_secs(20));
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes()).expect("send head");
    stream.write_all(body.as_bytes()).expect("send body");
    let mut answer = Vec::new();
    stream.read_to_end(&mut answer).expect("read the answer");
    parse(&answer)
}

/// The status and body of a raw HTTP/1.1 answer.
fn parse(answer: &[u8]) -> (u16, String) {
    let text = String::from_utf8_lossy(answer).into_owned();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("not an HTTP answer: {text:?}"));
    let body = text
        .split_once("\r\n\r\n")
        .map_or(String::new(), |(_, b)| b.to_owned());
    (status, body)
}

/// Reads until the server closes `stream` (EOF or reset); returns how long that took, or
/// `None` if it was still open after the stream's read timeout. Any answer bytes are kept in
/// `answer`.
fn wait_for_close(stream: &mut TcpStream, answer: &mut Vec<u8>) -> Option<Duration> {
    let started = Instant::now();
    let mut buf = [0u8; 4096];
    loop {
        match stream.read(&mut buf) {
            Ok(0) => return Some(started.elapsed()),
            Ok(n) => answer.extend_from_slice(&buf[..n]),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                return None;
            }
            Err(_) => return Some(started.elapsed()),
        }
    }
}

const ONE_PICK: &str = r#"{"rays":[{"origin":[33.3,45.1,100],"dir":[0,0,-1]}]}"#;

/// Short timeouts for the tests.
fn short_timeouts() -> ServerConfig {
    ServerConfig {
        idle_timeout: Duration::from_millis(800),
        body_timeout: Duration::from_millis(800),
        ..ServerConfig::default()
    }
}

#[test]
fn idle_half_header_and_half_body_connections_are_closed_after_the_timeouts() {
    let addr = start(short_timeouts());
    let limit = Duration::from_secs(5);

    // Idle from the start: never sends a byte.
    let mut idle = connect(addr, limit);
    // Half a header, then more header lines trickled in, never the blank line.
    let mut trickle = connect(addr, limit);
    trickle
        .write_all(b"POST /pick HTTP/1.1\r\nHost: localhost\r\n")
        .unwrap();
    // Keep-alive after one answered request.
    let mut kept = connect(addr, limit);
    let head = format!(
        "POST /pick HTTP/1.1\r\nHost: localhost\r\nContent-Length: {}\r\n\r\n{ONE_PICK}",
        ONE_PICK.len()
    );
    kept.write_all(head.as_bytes()).unwrap();
    // Half a body: 100 bytes announced, 10 sent.
    let mut half_body = connect(addr, limit);
    half_body
        .write_all(
            b"POST /pick HTTP/1.1\r\nHost: localhost\r\nContent-Length: 100\r\n\r\n{\"rays\":[",
        )
        .unwrap();

    let started = Instant::now();
    // Trickle a header line every 200 ms for 2 s (past the timeout); writes may fail once the
    // server has closed the connection.
    for i in 0..10 {
        std::thread::sleep(Duration::from_millis(200));
        if trickle
            .write_all(format!("X-Slow-{i}: 1\r\n").as_bytes())
            .is_err()
        {
            break;
        }
    }
    let trickled = wait_for_close(&mut trickle, &mut Vec::new());
    assert!(
        trickled.is_some(),
        "a connection trickling its headers stayed open {:?} after it started",
        started.elapsed()
    );
    assert!(
        started.elapsed() < Duration::from_millis(2000) + limit,
        "the trickling connection was closed late"
    );

    let closed = wait_for_close(&mut idle, &mut Vec::new());
    assert!(closed.is_some(), "an idle connection was never closed");
    assert!(
        started.elapsed() >= Duration::from_millis(600),
        "the idle connection was closed before its timeout"
    );

    let mut answer = Vec::new();
    assert!(
        wait_for_close(&mut kept, &mut answer).is_some(),
        "a keep-alive connection was never closed after its answer"
    );
    assert_eq!(parse(&answer).0, 200, "the kept connection's request");

    let mut answer = Vec::new();
    assert!(
        wait_for_close(&mut half_body, &mut answer).is_some(),
        "a connection with half a body was never closed"
    );
    let (status, body) = parse(&answer);
    assert_eq!(status, 408, "{body}");
    assert!(body.contains("\"error\""), "{body}");

    // The server still answers.
    assert_eq!(request(addr, "POST", "/pick", ONE_PICK).0, 200);
}

#[test]
fn normal_picks_answer_while_200_idle_connections_are_held() {
    let addr = start(ServerConfig::default());
    let held: Vec<TcpStream> = (0..200)
        .map(|_| connect(addr, Duration::from_secs(5)))
        .collect();
    for _ in 0..20 {
        let (status, body) = request(addr, "POST", "/pick", ONE_PICK);
        assert_eq!(status, 200, "{body}");
        assert!(body.contains("\"results\""), "{body}");
    }
    drop(held);
}

#[test]
fn connections_beyond_the_cap_wait_for_a_free_slot() {
    let addr = start(ServerConfig {
        max_connections: 4,
        ..short_timeouts()
    });
    let held: Vec<TcpStream> = (0..4)
        .map(|_| connect(addr, Duration::from_secs(5)))
        .collect();
    // Give the server time to accept the held ones, so that the next one is over the cap.
    std::thread::sleep(Duration::from_millis(100));
    let started = Instant::now();
    let (status, body) = request(addr, "POST", "/pick", ONE_PICK);
    assert_eq!(status, 200, "{body}");
    assert!(
        started.elapsed() >= Duration::from_millis(400),
        "a connection over the cap was served before the held ones timed out ({:?})",
        started.elapsed()
    );
    drop(held);
}

/// A pick's body and its rays each fit the budget but not both together: the body's memory goes
/// on to the rays (the body is parsed and dropped by then). It used to wait on its own body's
/// reservation for the whole wait, then hear that the server was busy.
#[test]
fn a_pick_whose_body_and_rays_together_pass_the_budget_is_answered() {
    let rays = 30_000;
    let one = r#"{"origin":[33.3,45.1,100],"dir":[0,0,-1]}"#;
    let body = format!(r#"{{"rays":[{}]}}"#, vec![one; rays].join(","));
    // The body's reservation is 9 bytes a body byte (11 MiB); the pick's, 873 bytes a ray
    // (25 MiB).
    let (body_bytes, budget) = (9 * body.len() as u64, 30u64 << 20);
    assert!(
        body_bytes < budget && body_bytes > budget / 3,
        "{body_bytes}"
    );
    let addr = start(ServerConfig {
        memory_budget: budget,
        memory_wait: Duration::from_secs(1),
        max_body_bytes: 64 << 20,
        ..ServerConfig::default()
    });
    let (status, answer) = request(addr, "POST", "/pick", &body);
    assert_eq!(status, 200, "{}", &answer[..answer.len().min(300)]);
    let value: serde_json::Value = serde_json::from_str(&answer).expect("JSON");
    assert_eq!(value["results"].as_array().map(Vec::len), Some(rays));
}

/// Uploads that declare a large body and send nothing hold only what they sent (a first
/// share), not what they declared: seven of them declaring 1 MiB each (9 MiB reserved apiece
/// for the body and its records) held a 63 MiB budget for the body timeout, and every other
/// request got 503.
#[test]
fn idle_uploads_hold_only_what_they_have_sent() {
    let addr = start(ServerConfig {
        memory_budget: 63 << 20,
        memory_wait: Duration::from_secs(1),
        max_body_bytes: 1 << 20,
        body_timeout: Duration::from_secs(20),
        ..ServerConfig::default()
    });
    let held: Vec<TcpStream> = (0..7)
        .map(|_| {
            let mut stream = connect(addr, Duration::from_secs(20));
            let head = format!(
                "POST /pick HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n\
                 Content-Length: {}\r\n\r\n{{",
                1 << 20
            );
            stream.write_all(head.as_bytes()).expect("send head");
            stream
        })
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    for _ in 0..3 {
        let (status, body) = request(addr, "POST", "/pick", ONE_PICK);
        assert_eq!(status, 200, "{body}");
    }
    drop(held);
}

/// A compressed body gets 415 and a sentence naming its coding (it was read as JSON and
/// refused for its bytes); `identity` is no coding.
#[test]
fn a_compressed_body_is_refused_with_415() {
    let addr = start(ServerConfig::default());
    for (coding, status) in [("gzip", 415), ("br", 415), ("identity", 200)] {
        let mut stream = connect(addr, Duration::from_secs(20));
        let head = format!(
            "POST /pick HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\
             Content-Encoding: {coding}\r\nContent-Type: application/json\r\n\
             Content-Length: {}\r\n\r\n{ONE_PICK}",
            ONE_PICK.len()
        );
        stream.write_all(head.as_bytes()).expect("send");
        let mut answer = Vec::new();
        stream.read_to_end(&mut answer).expect("read the answer");
        let (got, body) = parse(&answer);
        assert_eq!(got, status, "{coding}: {body}");
        if status == 415 {
            assert!(
                body.contains(&format!("Content-Encoding {coding}")),
                "{body}"
            );
        }
    }
}

/// A pick's memory stays reserved until its answer has been sent: a client that does not read
/// its 30 MB answer holds it, so a second such pick waits and then hears the server is busy,
/// and once the first client is gone the next is answered. The reservation used to end with
/// the handler, and slow readers held twice the budget uncounted.
#[test]
fn an_answer_holds_its_memory_until_it_is_sent() {
    let rays = 150_000;
    let one = r#"{"origin":[33.3,45.1,100],"dir":[0.01,0.02,-1]}"#;
    let body = format!(r#"{{"rays":[{}]}}"#, vec![one; rays].join(","));
    let addr = start(ServerConfig {
        memory_budget: 200 << 20,
        memory_wait: Duration::from_secs(1),
        max_body_bytes: 16 << 20,
        idle_timeout: Duration::from_secs(60),
        ..ServerConfig::default()
    });
    let head = format!(
        "POST /pick HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    let mut unread = connect(addr, Duration::from_secs(20));
    unread.write_all(head.as_bytes()).expect("send head");
    unread.write_all(body.as_bytes()).expect("send body");
    // Its first bytes: the answer is made and being sent.
    let mut first = [0u8; 16];
    unread
        .read_exact(&mut first)
        .expect("the answer's first bytes");
    assert!(first.starts_with(b"HTTP/1.1 200"), "{first:?}");
    let (status, answer) = request(addr, "POST", "/pick", &body);
    assert_eq!(status, 503, "{}", &answer[..answer.len().min(300)]);
    assert!(
        answer.contains("busy"),
        "{}",
        &answer[..answer.len().min(300)]
    );
    drop(unread);
    let started = Instant::now();
    loop {
        let (status, answer) = request(addr, "POST", "/pick", &body);
        if status == 200 {
            break;
        }
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "{status}: {}",
            &answer[..answer.len().min(300)]
        );
    }
}

#[test]
fn requests_over_the_memory_budget_get_503_and_the_next_answers() {
    let addr = start(ServerConfig {
        memory_budget: 64 << 20,
        ..ServerConfig::default()
    });
    // All hits with max_hits 1024 over 200 rays: well over 64 MiB reserved.
    let rays = vec![r#"{"origin":[33.3,45.1,100],"dir":[0,0,-1]}"#; 200].join(",");
    let big = format!(r#"{{"rays":[{rays}],"mode":"all","max_hits":1024}}"#);
    let (status, body) = request(addr, "POST", "/pick", &big);
    assert_eq!(status, 503, "{body}");
    let error: serde_json::Value = serde_json::from_str(&body).expect("a JSON error");
    let sentence = error["error"].as_str().expect("an error sentence");
    assert!(sentence.contains("memory"), "{sentence}");
    assert_eq!(
        sentence.matches(". ").count(),
        0,
        "one sentence: {sentence}"
    );

    // A 1M-pixel render is over the budget too.
    let (status, body) = request(addr, "GET", "/render?width=1024&height=1024", "");
    assert_eq!(status, 503, "{body}");

    // Normal requests still answer, the budget given back.
    for _ in 0..3 {
        let (status, body) = request(addr, "POST", "/pick", ONE_PICK);
        assert_eq!(status, 200, "{body}");
    }
    let small = format!(
        r#"{{"rays":[{}],"mode":"all","max_hits":16}}"#,
        vec![r#"{"origin":[33.3,45.1,100],"dir":[0,0,-1]}"#; 20].join(",")
    );
    assert_eq!(request(addr, "POST", "/pick", &small).0, 200);
    let (status, _) = request(addr, "GET", "/render?width=64&height=48", "");
    assert_eq!(status, 200);
}

#[test]
fn error_bodies_quote_at_most_a_short_piece_of_a_long_token() {
    let addr = start(ServerConfig::default());
    let b = "b".repeat(1_000_000);
    let x = "x".repeat(100_000);
    let spaced = "x y ".repeat(25_000);
    let shade = format!("/render?shade={}", "s".repeat(10_000));
    let query_field = format!("/render?{}=1", "q".repeat(10_000));
    let cases = [
        ("POST", "/pick", format!(r#"{{"rays":[],"{b}":1}}"#)),
        ("POST", "/pick", format!(r#"{{"rays":[],"mode":"{x}"}}"#)),
        (
            "POST",
            "/pick",
            format!(r#"{{"rays":[],"mode":"{spaced}"}}"#),
        ),
        (
            "POST",
            "/pick",
            format!(r#"{{"rays":[],"intersector":"{x}"}}"#),
        ),
        ("POST", "/objects", format!(r#"{{"mesh":0,"{b}":1}}"#)),
        ("POST", "/objects", format!(r#"{{"mesh":"{x}"}}"#)),
        ("PATCH", "/objects/0", format!(r#"{{"{b}":1}}"#)),
        ("GET", shade.as_str(), String::new()),
        ("GET", query_field.as_str(), String::new()),
    ];
    for (method, path, body) in &cases {
        let (status, answer) = request(addr, method, path, body);
        let what = format!("{method} {}…", &path[..path.len().min(20)]);
        assert_eq!(status, 400, "{what}: {}", &answer[..answer.len().min(300)]);
        let error: serde_json::Value = serde_json::from_str(&answer).expect("a JSON error");
        let sentence = error["error"].as_str().expect("an error sentence");
        assert!(sentence.contains('…'), "{what}: cut short: {sentence}");
        for run in ["b", "x", "s", "q", "x y "] {
            assert!(
                !sentence.contains(&run.repeat(61 / run.len() + 1)),
                "{what}: more than 60 characters of the token: {sentence}"
            );
        }
        assert!(sentence.chars().count() < 400, "{what}: {sentence}");
    }
}

/// `raypick --max-memory <max_memory> serve --backend cpu --addr 127.0.0.1:0 <more>` over the
/// example scene in a child process (the process budget is the process's own); killed on drop.
struct ChildServer(std::process::Child);

impl Drop for ChildServer {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl ChildServer {
    /// Starts it and reads its address from its first line.
    fn start(max_memory: &str, more: &[&str]) -> (ChildServer, SocketAddr) {
        use std::io::BufRead;
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_raypick"))
            .args(["--max-memory", max_memory, "serve", "--backend", "cpu"])
            .args(["--addr", "127.0.0.1:0"])
            .args(more)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::inherit())
            .spawn()
            .expect("the raypick binary starts");
        let stdout = child.stdout.take().expect("piped stdout");
        let server = ChildServer(child);
        let mut first = String::new();
        std::io::BufReader::new(stdout)
            .read_line(&mut first)
            .expect("read the server's first line");
        let addr = first
            .split_whitespace()
            .find_map(|w| w.strip_prefix("http://"))
            .and_then(|a| a.trim_end_matches('/').parse().ok())
            .unwrap_or_else(|| panic!("no listening address in {first:?}"));
        (server, addr)
    }
}

#[test]
fn work_over_the_process_memory_budget_gets_503() {
    // The requests' default budget stays within --max-memory; the render's 96,000 pixels
    // need more than 32 MiB.
    let (_server, addr) = ChildServer::start("32M", &[]);
    let (status, body) = request(addr, "GET", "/render?width=320&height=300", "");
    assert_eq!(status, 503, "{body}");
    assert!(body.contains("memory"), "{body}");
    let (status, body) = request(addr, "GET", "/render?width=32&height=30", "");
    assert_eq!(status, 200, "{body}");
}

#[test]
fn a_request_budget_over_the_process_budget_is_refused_at_start() {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_raypick"))
        .args(["--max-memory", "32M", "serve", "--memory-budget", "64M"])
        .args(["--addr", "127.0.0.1:0"])
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("the raypick binary starts");
    let deadline = Instant::now() + Duration::from_secs(30);
    while child.try_wait().expect("wait").is_none() {
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("raypick serve started with --memory-budget over --max-memory");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().expect("its output");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--memory-budget 64.0 MiB")
            && err.contains("32.0 MiB")
            && err.contains("--max-memory"),
        "{err}"
    );
}

/// A library user's `ServerConfig` is checked as the command line's flags are: a limit of 0
/// (every request refused) or a requests' budget over the process's is an error, not a server.
#[test]
fn a_server_with_limits_that_refuse_everything_is_not_made() {
    let built = Arc::new(
        BuiltScene::new(example_scene(), &BuildOptions::default()).expect("example builds"),
    );
    let configs = [
        ServerConfig {
            max_rays: 0,
            ..ServerConfig::default()
        },
        ServerConfig {
            max_connections: 0,
            ..ServerConfig::default()
        },
        ServerConfig {
            memory_budget: raypick::budget::limit() + 1,
            ..ServerConfig::default()
        },
    ];
    for config in configs {
        let made = raypick::server::Server::new(built.clone(), Backend::Cpu, config.clone());
        assert!(made.is_err(), "{config:?} made a server");
    }
}

/// A client that sends a costly pick and goes away no longer holds the picking worker until
/// the pick is done: before, a request of a few thousand rays through a stack of 100,000
/// triangles at one place (what `POST /objects` lets a client add) kept every other client
/// waiting for all of it, its client long gone. Now the worker picks in steps and stops when
/// no one waits for the answer, so the next client is answered within a few steps of the first
/// one's leaving. Timed against one step measured in the same run (the machine's speed cancels
/// out): the abandoned pick is 200 steps' work, and the next client may wait a few steps and
/// the step in flight (steps double on a fast machine, up to the work done so far).
#[test]
fn a_costly_pick_whose_client_left_stops_holding_the_worker() {
    use raypick::Scene;
    use raypick::scene::Mesh;
    let mut scene = Scene::new();
    let stack = Mesh {
        positions: vec![
            glam::DVec3::new(0.0, 0.0, 0.0),
            glam::DVec3::new(1.0, 0.0, 0.0),
            glam::DVec3::new(0.0, 1.0, 0.0),
        ],
        triangles: vec![[0, 1, 2]; 100_000],
    };
    scene.add_mesh("stack", stack).unwrap();
    let built = Arc::new(BuiltScene::new(scene, &BuildOptions::default()).unwrap());
    let addr = crate::common::serve(built, Backend::Cpu, ServerConfig::default());
    let rays = |n: usize| {
        let ray = r#"{"origin": [0.2, 0.2, 5], "dir": [0, 0, -1]}"#;
        format!(r#"{{"rays": [{}]}}"#, vec![ray; n].join(","))
    };
    // One step's work (256 rays), answered whole: the yardstick.
    let start = Instant::now();
    let (status, _) = request(addr, "POST", "/pick", &rays(256));
    assert_eq!(status, 200);
    let step = start.elapsed();
    // 200 steps' work, from a client that gives up after two steps (at least half a second).
    let patience = (step * 2).max(Duration::from_millis(500));
    let body = rays(256 * 200);
    let mut stream = connect(addr, patience);
    let head = format!(
        "POST /pick HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes()).unwrap();
    stream.write_all(body.as_bytes()).unwrap();
    let mut answer = [0u8; 16];
    let left = stream.read(&mut answer);
    assert!(
        left.is_err(),
        "the costly pick answered within {patience:?}"
    );
    drop(stream);
    let gone = Instant::now();
    let (status, _) = request(addr, "POST", "/pick", &rays(1));
    let waited = gone.elapsed();
    assert_eq!(status, 200);
    assert!(
        waited < step * 8 + patience * 2,
        "the next pick waited {waited:?}, {:.1} steps of {step:?}: the worker went on with the \
         abandoned pick",
        waited.as_secs_f64() / step.as_secs_f64()
    );
}

/// A client that stays connected could hold the worker for hours with one costly request (a
/// million rays through a scene where each costs milliseconds: every other client's picks
/// waited). The worker now stops a request's steps once they pass the work limit
/// (`--max-work-seconds`): the request gets 413 with the count answered and what to do, and the
/// next request is answered. Here the limit is a nanosecond, so every request stops after its
/// first step of 256 rays: one of 256 rays or fewer is answered, a larger pick and a render are
/// stopped.
#[test]
fn requests_past_the_work_limit_are_stopped_with_413() {
    let addr = start(ServerConfig {
        max_work: Duration::from_nanos(1),
        ..ServerConfig::default()
    });
    let rays = |n: usize| {
        let ray = r#"{"origin": [10, 10, 50], "dir": [0, 0, -1]}"#;
        format!("{{\"rays\": [{}]}}", vec![ray; n].join(","))
    };
    let (status, body) = request(addr, "POST", "/pick", &rays(1000));
    assert_eq!(status, 413, "{body}");
    assert!(
        body.contains("this pick was stopped after 256 of its 1000 rays")
            && body.contains("--max-work-seconds")
            && body.contains("send fewer rays"),
        "{body}"
    );
    let (status, body) = request(addr, "GET", "/render", "");
    assert_eq!(status, 413, "{body}");
    assert!(
        body.contains("this render was stopped after 256 of its 307200 pixels"),
        "{body}"
    );
    let (status, body) = request(addr, "POST", "/pick", &rays(256));
    assert_eq!(status, 200, "{body}");
    assert_eq!(body.matches("\"hit\":true").count(), 256, "{body:.200}");
}

/// The work limit is each request's: a small pick batched behind a costly one (the two asked
/// within the batch window) is answered on a clock of its own, not refused for the other's
/// time (it was: "stopped after 0 of its 1 rays").
#[test]
fn the_work_limit_is_each_requests_own_in_a_batch() {
    let addr = start(ServerConfig {
        max_work: Duration::from_nanos(1),
        // Wide: the second request is sent 100 ms after the first, and a loaded machine must
        // not make it miss the batch (the window costs time only when they do not meet).
        batch_window: Duration::from_secs(3),
        ..ServerConfig::default()
    });
    let rays = |n: usize| {
        let ray = r#"{"origin": [10, 10, 50], "dir": [0, 0, -1]}"#;
        format!("{{\"rays\": [{}]}}", vec![ray; n].join(","))
    };
    let big = rays(1000);
    let costly = std::thread::spawn(move || request(addr, "POST", "/pick", &big));
    std::thread::sleep(Duration::from_millis(100));
    let (status, body) = request(addr, "POST", "/pick", &rays(1));
    assert_eq!(status, 200, "{body}");
    let (status, body) = costly.join().unwrap();
    assert_eq!(status, 413, "{body}");
    assert!(
        body.contains("stopped after 256 of its 1000 rays"),
        "{body}"
    );
    let stats = request(addr, "GET", "/stats", "").1;
    assert!(
        stats.contains("\"batched_requests\":2"),
        "batched together: {stats}"
    );
}

/// Requests hyper refuses before any route sees them (a malformed request line or header, a
/// URI over 65,534 bytes, over 100 header fields) get their 400, 414 or 431 with a sentence, as
/// JSON like every other error, and the connection is closed; a well-formed request on the same
/// kept-alive connection before a malformed one is answered as usual.
#[test]
fn requests_hyper_refuses_get_their_status_with_a_sentence() {
    let addr = start(ServerConfig::default());
    let raw = |bytes: Vec<u8>| {
        let mut stream = connect(addr, Duration::from_secs(20));
        stream.write_all(&bytes).expect("send");
        let mut answer = Vec::new();
        assert!(
            wait_for_close(&mut stream, &mut answer).is_some(),
            "the connection stays open"
        );
        answer
    };
    let long_uri = [
        b"GET /".as_slice(),
        &[b'a'; 70_000],
        b" HTTP/1.1\r\nHost: localhost\r\n\r\n",
    ]
    .concat();
    let many_fields = [
        b"GET /scene HTTP/1.1\r\nHost: localhost\r\n".to_vec(),
        (0..150)
            .flat_map(|i| format!("X-{i}: 1\r\n").into_bytes())
            .collect(),
        b"\r\n".to_vec(),
    ]
    .concat();
    let cases: [(Vec<u8>, u16, &str); 6] = [
        (
            b"GARBAGE\r\n\r\n".to_vec(),
            400,
            "could not be read as HTTP:",
        ),
        (
            b"GET /scene HTTP/1.1\r\nHost: localhost\r\nBad Header\r\n\r\n".to_vec(),
            400,
            "could not be read as HTTP:",
        ),
        (long_uri, 414, "URI is too long"),
        (many_fields, 431, "at most 100 header fields"),
        (
            b"GET /stats HTTP/1.1\r\nHost: localhost\r\n\r\nGET /stats HTTP/1.1\r\nHost: \
              localhost\r\nBad Header\r\n\r\n"
                .to_vec(),
            400,
            "could not be read as HTTP:",
        ),
        // hyper answers in the version of the connection's last request.
        (
            b"GET /stats HTTP/1.0\r\nHost: localhost\r\nConnection: keep-alive\r\n\r\n\
              GET /st ats HTTP/1.0\r\n\r\n"
                .to_vec(),
            400,
            "could not be read as HTTP:",
        ),
    ];
    for (request, status, sentence) in cases {
        let answer = raw(request);
        let text = String::from_utf8_lossy(&answer).into_owned();
        // The kept-alive case: the first request's answer, then the refusal.
        let at = ["HTTP/1.0 ", "HTTP/1.1 "].map(|line| text.rfind(line).unwrap_or(0));
        let last = &text[at[0].max(at[1])..];
        let (got, body) = parse(last.as_bytes());
        assert_eq!(got, status, "{text}");
        let value: serde_json::Value =
            serde_json::from_str(&body).unwrap_or_else(|e| panic!("{e}: {text}"));
        let said = value["error"].as_str().unwrap_or_default();
        assert!(said.contains(sentence), "{text}");
        assert!(
            last.contains(&format!("content-length: {}\r\n", body.len())),
            "{text}"
        );
        if text.len() > last.len() {
            assert!(text[8..].starts_with(" 200 OK"), "{text}");
        }
    }
}

/// A client that takes a large answer steadily but slower than the socket wakes the server's
/// writer (which waits for a third of a send buffer of up to several MiB to drain: longer than
/// the idle timeout at this pace) gets the whole answer: the bytes it has acknowledged count as
/// progress. (A 26 MB answer read at 30–100 KB/s was cut short at the idle timeout.)
#[cfg(target_os = "linux")]
#[test]
fn a_slow_but_steady_reader_gets_the_whole_answer() {
    use std::os::fd::AsRawFd;
    let addr = start(ServerConfig {
        idle_timeout: Duration::from_secs(1),
        ..ServerConfig::default()
    });
    let ray = r#"{"origin":[33.3,45.1,100],"dir":[0.01,0.02,-1]}"#;
    let body = format!(r#"{{"rays":[{}]}}"#, vec![ray; 30_000].join(","));
    let mut stream = connect(addr, Duration::from_secs(20));
    // A small receive buffer, so the server's writes wait on this reader.
    let size: libc::c_int = 16 << 10;
    // SAFETY: SO_RCVBUF reads one int from the pointer, which points to one.
    let set = unsafe {
        libc::setsockopt(
            stream.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_RCVBUF,
            (&size as *const libc::c_int).cast(),
            size_of::<libc::c_int>() as libc::socklen_t,
        )
    };
    assert_eq!(set, 0, "set the receive buffer");
    let head = format!(
        "POST /pick HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes()).expect("send head");
    stream.write_all(body.as_bytes()).expect("send body");
    // About 600 KB/s, in 16 KiB reads.
    let (mut answer, mut buf) = (Vec::new(), vec![0u8; 16 << 10]);
    loop {
        match stream.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => answer.extend_from_slice(&buf[..n]),
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    let text = String::from_utf8_lossy(&answer);
    let (head, body) = text.split_once("\r\n\r\n").expect("an answer");
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    let length: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("content-length: "))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no length in {head}"));
    assert!(
        length > 5 << 20,
        "an answer of {length} bytes waits on no one"
    );
    assert_eq!(body.len(), length, "the answer was cut short");
}

/// A request whose body the server does not read whole (declared over the limit, or broken
/// chunks) ends its connection, and its answer says so (`connection: close`), with its sentence.
#[test]
fn an_unread_body_ends_the_connection_and_the_answer_says_so() {
    let addr = start(ServerConfig::default());
    let cases: [(&[u8], u16, &str); 2] = [
        (
            b"POST /pick HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n\
              Content-Length: 100000000\r\n\r\n{\"rays\":",
            413,
            "larger than this server's limit",
        ),
        (
            b"POST /pick HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n\
              Transfer-Encoding: chunked\r\n\r\nzz\r\n{}\r\n0\r\n\r\n",
            400,
            // What was wrong, not only hyper's "error reading a body from connection".
            "could not be read: error reading a body from connection: Invalid chunk size line",
        ),
    ];
    for (request, status, sentence) in cases {
        let mut stream = connect(addr, Duration::from_secs(20));
        stream.write_all(request).expect("send");
        assert_closing_answer(&mut stream, status, sentence, "");
    }
}

/// Reads `stream` until the server closes it, and checks that the answer has `status`, a body
/// with `sentence` in it, and `connection: close` in its head (`what` names the case).
fn assert_closing_answer(stream: &mut TcpStream, status: u16, sentence: &str, what: &str) {
    let mut answer = Vec::new();
    assert!(
        wait_for_close(stream, &mut answer).is_some(),
        "{what}: the connection stays open"
    );
    let text = String::from_utf8_lossy(&answer).into_owned();
    let (got, body) = parse(&answer);
    assert_eq!(got, status, "{what}: {text}");
    assert!(body.contains(sentence), "{what}: {text}");
    assert!(closes(&text), "{what}: {text}");
}

/// An answer given without reading the request's body — another site's `POST` (403), an
/// unknown page (404), a pick whose body alone is over the memory budget (503), a `DELETE` with
/// a body — keeps the connection when the body is small and sent whole (drained, as hyper does),
/// and otherwise says `connection: close` and ends it: a 3 MB body, a small body the client
/// holds back for `Expect: 100-continue`. An HTTP/1.0 client's closing answer says only
/// `close`, in HTTP/1.0.
#[test]
fn an_answer_that_leaves_the_body_unread_says_connection_close() {
    let addr = start(ServerConfig {
        memory_budget: 1 << 20,
        ..ServerConfig::default()
    });
    let head = |method: &str, path: &str, extra: &str, length: usize| {
        format!(
            "{method} {path} HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n\
             {extra}Content-Length: {length}\r\n\r\n"
        )
    };
    let pick = head("POST", "/pick", "", ONE_PICK.len()) + ONE_PICK;
    let cases = [
        (
            "POST",
            "/pick",
            "Origin: http://elsewhere.example\r\n",
            403,
            "another web site",
        ),
        ("POST", "/no-such-page", "", 404, "no such page"),
        ("POST", "/pick", "", 503, "budget"),
        ("DELETE", "/objects/99", "", 404, "99"),
    ];
    for (method, path, extra, status, sentence) in cases {
        for length in [100, 3_000_000] {
            let what = format!("{method} {path} with a {length}-byte body");
            if status == 503 && length < 1 << 20 {
                continue;
            }
            let mut stream = connect(addr, Duration::from_secs(20));
            if length > 100 {
                stream
                    .write_all(head(method, path, extra, length).as_bytes())
                    .expect("send head");
                // The server may close while the body is still on its way: a failed send is
                // fine.
                let mut sender = stream.try_clone().expect("clone the stream");
                let body = std::thread::spawn(move || {
                    let _ = sender.write_all(&vec![b' '; length]);
                });
                assert_closing_answer(&mut stream, status, sentence, &what);
                body.join().expect("the sender");
                continue;
            }
            // Sent whole, at once: the server waits only briefly for an unread body's rest.
            let request = head(method, path, extra, length) + &" ".repeat(length);
            stream.write_all(request.as_bytes()).expect("send");
            let text = read_one_answer(&mut stream);
            assert_eq!(parse(text.as_bytes()).0, status, "{what}: {text}");
            assert!(text.contains(sentence), "{what}: {text}");
            assert!(!closes(&text), "{what}: {text}");
            // The connection takes the next request.
            stream.write_all(pick.as_bytes()).expect("send a pick");
            let text = read_one_answer(&mut stream);
            assert_eq!(parse(text.as_bytes()).0, 200, "{what}, then a pick: {text}");
        }
    }
    // A body held back for `100 Continue` is not asked for: the connection ends.
    let mut stream = connect(addr, Duration::from_secs(20));
    let expect = "Origin: http://elsewhere.example\r\nExpect: 100-continue\r\n";
    stream
        .write_all(head("POST", "/pick", expect, 100).as_bytes())
        .expect("send head");
    assert_closing_answer(&mut stream, 403, "another web site", "Expect: 100-continue");
    // HTTP/1.0 with keep-alive asked for: an HTTP/1.0 answer saying `close` alone.
    let mut stream = connect(addr, Duration::from_secs(20));
    let old = "POST /nope HTTP/1.0\r\nHost: localhost\r\nConnection: keep-alive\r\n\
               Content-Length: 3000000\r\n\r\n";
    stream.write_all(old.as_bytes()).expect("send head");
    let mut sender = stream.try_clone().expect("clone the stream");
    let body = std::thread::spawn(move || {
        let _ = sender.write_all(&vec![b' '; 3_000_000]);
    });
    let mut answer = Vec::new();
    assert!(
        wait_for_close(&mut stream, &mut answer).is_some(),
        "HTTP/1.0 stays open"
    );
    body.join().expect("the sender");
    let text = String::from_utf8_lossy(&answer).into_owned();
    assert!(text.starts_with("HTTP/1.0 404"), "{text}");
    assert!(closes(&text), "{text}");
    assert!(!text.to_ascii_lowercase().contains("keep-alive"), "{text}");
    // A pick whose body is read: no `connection: close`, and a second pick on the connection.
    let mut stream = connect(addr, Duration::from_secs(20));
    for _ in 0..2 {
        stream.write_all(pick.as_bytes()).expect("send");
        let text = read_one_answer(&mut stream);
        assert_eq!(parse(text.as_bytes()).0, 200, "{text}");
        assert!(!closes(&text), "{text}");
    }
}

/// Whether an answer's head says `connection: close`.
fn closes(answer: &str) -> bool {
    let head = answer.split("\r\n\r\n").next().unwrap_or_default();
    head.lines()
        .any(|l| l.eq_ignore_ascii_case("connection: close"))
}

/// One answer read from a kept-alive connection: its head and its `content-length` bytes.
fn read_one_answer(stream: &mut TcpStream) -> String {
    let mut answer: Vec<u8> = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        if let Some(end) = answer.windows(4).position(|w| w == b"\r\n\r\n") {
            let head = String::from_utf8_lossy(&answer[..end]).into_owned();
            let length = head
                .lines()
                .find_map(|l| {
                    let (name, value) = l.split_once(':')?;
                    name.eq_ignore_ascii_case("content-length")
                        .then(|| value.trim().parse::<usize>().ok())?
                })
                .expect("a content-length");
            if answer.len() - (end + 4) >= length {
                return String::from_utf8_lossy(&answer).into_owned();
            }
        }
        let n = stream.read(&mut buf).expect("the answer");
        assert!(n > 0, "closed after {:?}", String::from_utf8_lossy(&answer));
        answer.extend_from_slice(&buf[..n]);
    }
}

/// An HTTP/2 client that starts with the connection preface (`curl --http2-prior-knowledge`)
/// is answered in HTTP/2: an empty SETTINGS frame, then GOAWAY with HTTP_1_1_REQUIRED and a
/// sentence, and the connection ends once the client closes (hyper, serving HTTP/1 only,
/// reset it without a word). So too where the preface comes in pieces (it was given to hyper
/// then, which reset the connection). HTTP/1 clients are served as before, requests sent a
/// byte at a time (one starting with the preface's 'P') included.
#[test]
fn an_http2_client_is_told_to_use_http1() {
    let addr = start(ServerConfig::default());
    // The preface, then the client's SETTINGS frame (empty).
    let opening: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\x00\x00\x00\x04\x00\x00\x00\x00\x00";
    for pieces in [
        vec![opening.len()],
        vec![1, 2, 5, 7, 1],
        vec![1; 16],
        vec![15, 1, 3],
    ] {
        let mut stream = connect(addr, Duration::from_secs(20));
        let mut sent = 0;
        for n in pieces {
            stream.write_all(&opening[sent..sent + n]).expect("send");
            stream.flush().expect("send");
            std::thread::sleep(Duration::from_millis(20));
            sent += n;
        }
        stream.write_all(&opening[sent..]).expect("send");
        assert_told_to_use_http1(&mut stream);
    }
    let (status, _) = request(addr, "GET", "/scene", "");
    assert_eq!(status, 200);
    // An HTTP/1 request whose first bytes could begin the preface, sent a byte at a time.
    let body = ONE_PICK;
    for method in ["POST", "PUT"] {
        let mut stream = connect(addr, Duration::from_secs(20));
        let text = format!(
            "{method} /pick HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\
             Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        for byte in text.as_bytes().iter().take(20) {
            stream.write_all(&[*byte]).expect("send");
            std::thread::sleep(Duration::from_millis(2));
        }
        stream.write_all(&text.as_bytes()[20..]).expect("send");
        let mut answer = Vec::new();
        stream.read_to_end(&mut answer).expect("read the answer");
        let (status, _) = parse(&answer);
        assert_eq!(status, if method == "POST" { 200 } else { 405 }, "{method}");
    }
}

/// Reads the HTTP/2 refusal (SETTINGS, GOAWAY with HTTP_1_1_REQUIRED and its sentence) from
/// `stream`, closes the client's side and checks that the server then ends the connection.
fn assert_told_to_use_http1(stream: &mut TcpStream) {
    let mut answer = vec![0u8; 512];
    let mut got = 0;
    let why = b"raypick serves HTTP/1.1 only";
    while got < 9 + 17 + why.len() {
        match stream.read(&mut answer[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) => panic!("after {got} bytes: {e}"),
        }
    }
    let answer = &answer[..got];
    assert_eq!(
        &answer[..9],
        &[0, 0, 0, 4, 0, 0, 0, 0, 0],
        "SETTINGS: {answer:?}"
    );
    let goaway = &answer[9..];
    assert_eq!(goaway[3], 7, "a GOAWAY frame: {answer:?}");
    assert_eq!(
        &goaway[13..17],
        &[0, 0, 0, 0xd],
        "HTTP_1_1_REQUIRED: {answer:?}"
    );
    assert_eq!(&goaway[17..], why);
    assert_eq!(
        u32::from_be_bytes([0, goaway[0], goaway[1], goaway[2]]) as usize,
        8 + why.len()
    );
    // The client closes; the server ends the connection.
    stream.shutdown(std::net::Shutdown::Write).expect("close");
    let mut rest = Vec::new();
    stream.read_to_end(&mut rest).expect("the connection ends");
    assert!(rest.is_empty(), "{rest:?}");
}
