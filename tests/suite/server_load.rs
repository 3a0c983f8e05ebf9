//! The `raypick serve` load test on loopback (issue 11, "Targets" → "Server load test"): this
//! file owns it. The server runs in a CHILD process (the crate's own `raypick` binary, `serve
//! --addr 127.0.0.1:0 --backend cpu --idle-timeout 2` over the built-in example scene) so that
//! its resident memory can be read from `/proc/<pid>/status`; it is killed when the test ends,
//! panics included.
//!
//! While 200 idle TCP connections are held open, 32 client threads send 100 requests each on
//! keep-alive connections: normal `POST /pick` requests of 300 rays (modes closest, any and all),
//! and, every 10th request of four of the clients, a heavy one (mode `all` with `"max_hits":
//! 1024` over 1000 rays, or a 1000 x 1000 `GET /render`). Heavy requests may get 503 from the
//! server's memory budget and are counted apart. Checks:
//!
//! - every normal request answers 200, byte-identical to the same request sent alone before the
//!   load (answers carry no timing fields); heavy requests answer 200 (byte-identical too) or 503,
//!   nothing else;
//! - the server's VmRSS, sampled every 50 ms, peaks at most 512 MB above idle and is back within
//!   64 MB of idle 3 s after the load;
//! - the 200 idle connections have been closed by the server after the 2 s idle timeout.
//!
//! Loopback only (127.0.0.1), every loop bounded; it stops by itself in well under 90 s on two
//! cores. Run it with `--nocapture` to see the figures (requests/s, errors, 503s, RSS).

use serde_json::{Value, json};
use std::io::{BufRead, BufReader, ErrorKind, Read};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Client threads, and requests per client thread.
const CLIENTS: usize = 32;
const REQUESTS: usize = 100;
/// Clients that send a heavy request every 10th request.
const HEAVY_CLIENTS: usize = 4;
/// Idle connections held open during the load.
const IDLE_CONNECTIONS: usize = 200;
/// Rays per normal pick request, and distinct normal bodies.
const NORMAL_RAYS: usize = 300;
const NORMAL_BODIES: usize = 6;
/// Rays of a heavy all-hits request (x 1024 `max_hits`).
const HEAVY_RAYS: usize = 1000;
/// The server's idle timeout, seconds.
const IDLE_TIMEOUT_S: u64 = 2;
const MB: u64 = 1 << 20;

/// The server child process; killed and reaped on drop (also when the test panics).
struct ServerProcess {
    child: Child,
    base: String,
}

impl Drop for ServerProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl ServerProcess {
    /// Starts `raypick serve` on a free loopback port (port 0; the address is read from the
    /// server's first line on standard output) and waits until `GET /scene` answers.
    fn start() -> ServerProcess {
        let mut child = Command::new(env!("CARGO_BIN_EXE_raypick"))
            .args([
                "serve",
                "--addr",
                "127.0.0.1:0",
                "--backend",
                "cpu",
                "--idle-timeout",
                &IDLE_TIMEOUT_S.to_string(),
                // Fixed, not a share of the machine's memory (unless that is less: the server
                // refuses a budget over --max-memory): a heavy all-hits pick (about 600 MB) and
                // a render (about 370 MB) fit together, so the normal picks queued behind them
                // never wait out the budget's 5 s.
                "--memory-budget",
                &(1536u64 << 20)
                    .min(raypick::budget::default_limit())
                    .to_string(),
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("the raypick binary starts");
        let stdout = child.stdout.take().expect("piped stdout");
        // The guard exists from here on, so a panic below still kills the child.
        let mut server = ServerProcess {
            child,
            base: String::new(),
        };
        let mut lines = BufReader::new(stdout);
        let mut first = String::new();
        lines
            .read_line(&mut first)
            .expect("read the server's first line");
        let url = first
            .split_whitespace()
            .find(|w| w.starts_with("http://127.0.0.1:"))
            .unwrap_or_else(|| panic!("no listening address in {first:?}"));
        server.base = url.trim_end_matches('/').to_owned();
        // Keep draining whatever else the server prints so that it never blocks on a full pipe.
        std::thread::spawn(move || {
            let mut sink = Vec::new();
            let _ = lines.read_to_end(&mut sink);
        });
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Ok(mut r) = agent().get(&format!("{}/scene", server.base)).call()
                && r.status().as_u16() == 200
            {
                let _ = r.body_mut().read_to_vec();
                break;
            }
            assert!(
                Instant::now() < deadline,
                "the server did not answer within 60 s"
            );
            if let Ok(Some(status)) = server.child.try_wait() {
                panic!("the server exited: {status}");
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        server
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }
}

/// The process's resident memory in bytes (VmRSS of /proc/<pid>/status).
fn rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("read status");
    let line = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .expect("VmRSS line");
    let kb: u64 = line
        .split_whitespace()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .expect("VmRSS value");
    kb * 1024
}

fn agent() -> ureq::Agent {
    crate::common::http_agent(Duration::from_secs(120))
}

/// One request: what to send.
#[derive(Clone)]
enum Request {
    Post(String),
    Get(String),
}

/// Sends `request` on `agent`: the status and body bytes, or the transport error.
fn send(agent: &ureq::Agent, base: &str, request: &Request) -> Result<(u16, Vec<u8>), String> {
    let response = match request {
        Request::Post(body) => agent
            .post(&format!("{base}/pick"))
            .header("content-type", "application/json")
            .send(body.as_str()),
        Request::Get(path) => agent.get(&format!("{base}{path}")).call(),
    };
    let mut response = response.map_err(|e| e.to_string())?;
    let status = response.status().as_u16();
    let body = response
        .body_mut()
        .with_config()
        .limit(256 << 20)
        .read_to_vec()
        .map_err(|e| e.to_string())?;
    Ok((status, body))
}

/// A small deterministic generator (splitmix64) for the rays.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// `count` rays over the scene bounds `lo..hi`: mostly from above looking down (tilted), some
/// horizontal through the middle heights, some from inside in any direction.
fn rays(lo: [f64; 3], hi: [f64; 3], count: usize, seed: u64) -> Vec<Value> {
    let mut rng = Rng(seed.wrapping_mul(0x1234_5678_9ABC_DEF1) ^ 0xDEAD_BEEF);
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    (0..count)
        .map(|i| {
            let x = lerp(lo[0], hi[0], rng.next());
            let y = lerp(lo[1], hi[1], rng.next());
            let (origin, dir) = match i % 5 {
                0..=2 => (
                    [x, y, hi[2] + 10.0],
                    [rng.next() - 0.5, rng.next() - 0.5, -1.0],
                ),
                3 => {
                    let z = lerp(lo[2], hi[2], rng.next());
                    let a = rng.next() * std::f64::consts::TAU;
                    ([x, y, z], [a.cos(), a.sin(), 0.0])
                }
                _ => {
                    let z = lerp(lo[2], hi[2], rng.next());
                    (
                        [x, y, z],
                        [rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5],
                    )
                }
            };
            json!({"origin": origin, "dir": dir})
        })
        .collect()
}

fn bounds(scene: &Value, which: &str) -> [f64; 3] {
    let v = &scene["bounds"][which];
    [0, 1, 2].map(|i| v[i].as_f64().expect("bound coordinate"))
}

/// Counters shared by the client threads.
#[derive(Default)]
struct Counts {
    normal_ok: AtomicU64,
    normal_errors: AtomicU64,
    heavy_ok: AtomicU64,
    heavy_503: AtomicU64,
    heavy_errors: AtomicU64,
}

#[test]
fn server_under_load_keeps_answers_memory_and_idle_timeout() {
    let server = ServerProcess::start();
    let base = server.base.clone();
    let pid = server.pid();
    let fresh_rss = rss(pid);
    let setup = agent();

    // The requests, and each one's answer when sent alone.
    let (status, scene) = send(&setup, &base, &Request::Get("/scene".into())).expect("scene");
    assert_eq!(status, 200);
    let scene: Value = serde_json::from_slice(&scene).expect("scene JSON");
    let (lo, hi) = (bounds(&scene, "min"), bounds(&scene, "max"));
    let normal: Vec<Request> = (0..NORMAL_BODIES)
        .map(|k| {
            let mut body = json!({"rays": rays(lo, hi, NORMAL_RAYS, k as u64)});
            match k % 3 {
                0 => body["mode"] = json!("closest"),
                1 => body["mode"] = json!("any"),
                _ => {
                    body["mode"] = json!("all");
                    body["max_hits"] = json!(16);
                }
            }
            Request::Post(body.to_string())
        })
        .collect();
    let heavy = [
        Request::Post(
            json!({"rays": rays(lo, hi, HEAVY_RAYS, 99), "mode": "all", "max_hits": 1024})
                .to_string(),
        ),
        Request::Get("/render?width=1000&height=1000&shade=normal".into()),
    ];
    let solo = |request: &Request, what: &str| {
        let (status, body) = send(&setup, &base, request).expect(what);
        assert_eq!(
            status,
            200,
            "{what} alone: {}",
            String::from_utf8_lossy(&body)
        );
        body
    };
    let normal_solo: Vec<Vec<u8>> = normal.iter().map(|r| solo(r, "normal pick")).collect();
    // Answers carry no per-request timing: the same request answers the same bytes twice.
    assert_eq!(solo(&normal[0], "normal pick again"), normal_solo[0]);
    let heavy_solo: Vec<Vec<u8>> = heavy.iter().map(|r| solo(r, "heavy request")).collect();
    drop(setup);

    // Idle: the warmed-up server at rest.
    std::thread::sleep(Duration::from_secs(1));
    let idle_rss = rss(pid);
    eprintln!(
        "server rss: fresh {} MB, idle after the solo requests {} MB; answers: normal {:?} \
         bytes, heavy all-hits {} bytes, 1000 x 1000 render {} bytes",
        fresh_rss / MB,
        idle_rss / MB,
        normal_solo.iter().map(Vec::len).collect::<Vec<_>>(),
        heavy_solo[0].len(),
        heavy_solo[1].len(),
    );

    // Memory sampler.
    let stop = Arc::new(AtomicBool::new(false));
    let peak = Arc::new(AtomicU64::new(idle_rss));
    let sampler = {
        let (stop, peak) = (stop.clone(), peak.clone());
        std::thread::spawn(move || {
            // Bounded: at most 10 minutes of samples.
            for _ in 0..12_000 {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                if let Ok(status) = std::fs::read_to_string(format!("/proc/{pid}/status"))
                    && let Some(kb) = status
                        .lines()
                        .find(|l| l.starts_with("VmRSS:"))
                        .and_then(|l| l.split_whitespace().nth(1))
                        .and_then(|v| v.parse::<u64>().ok())
                {
                    peak.fetch_max(kb * 1024, Ordering::Relaxed);
                }
                std::thread::sleep(Duration::from_millis(50));
            }
        })
    };

    // The idle connections, held open (nothing sent) from just before the load.
    let addr = base.trim_start_matches("http://").to_owned();
    let idle: Vec<TcpStream> = (0..IDLE_CONNECTIONS)
        .map(|_| TcpStream::connect(&addr).expect("idle connection"))
        .collect();
    let idle_opened = Instant::now();
    // Accepted and open (not refused or closed at once): a peek finds nothing to read yet.
    for stream in &idle {
        stream.set_nonblocking(true).expect("nonblocking");
        let mut byte = [0u8; 1];
        let open = matches!(stream.peek(&mut byte), Err(e) if e.kind() == ErrorKind::WouldBlock);
        assert!(open, "an idle connection was closed at once");
        stream.set_nonblocking(false).expect("blocking");
    }

    // The load.
    let counts = Arc::new(Counts::default());
    let normal = Arc::new(normal);
    let normal_solo = Arc::new(normal_solo);
    let heavy = Arc::new(heavy);
    let heavy_solo = Arc::new(heavy_solo);
    let start = Instant::now();
    let clients: Vec<_> = (0..CLIENTS)
        .map(|c| {
            let (base, counts) = (base.clone(), counts.clone());
            let (normal, normal_solo) = (normal.clone(), normal_solo.clone());
            let (heavy, heavy_solo) = (heavy.clone(), heavy_solo.clone());
            std::thread::spawn(move || {
                let agent = agent();
                let mut failures = Vec::new();
                for r in 0..REQUESTS {
                    if c < HEAVY_CLIENTS && r % 10 == 9 {
                        let k = (c + r / 10) % heavy.len();
                        match send(&agent, &base, &heavy[k]) {
                            Ok((200, body)) if body == heavy_solo[k] => {
                                counts.heavy_ok.fetch_add(1, Ordering::Relaxed);
                            }
                            Ok((503, _)) => {
                                counts.heavy_503.fetch_add(1, Ordering::Relaxed);
                            }
                            other => {
                                counts.heavy_errors.fetch_add(1, Ordering::Relaxed);
                                failures
                                    .push(format!("client {c} heavy {k}: {}", describe(&other)));
                            }
                        }
                    } else {
                        let k = (c * 7 + r) % normal.len();
                        match send(&agent, &base, &normal[k]) {
                            Ok((200, body)) if body == normal_solo[k] => {
                                counts.normal_ok.fetch_add(1, Ordering::Relaxed);
                            }
                            other => {
                                counts.normal_errors.fetch_add(1, Ordering::Relaxed);
                                failures
                                    .push(format!("client {c} normal {k}: {}", describe(&other)));
                            }
                        }
                    }
                }
                failures
            })
        })
        .collect();
    let failures: Vec<String> = clients
        .into_iter()
        .flat_map(|t| t.join().expect("client thread"))
        .collect();
    let elapsed = start.elapsed();
    stop.store(true, Ordering::Relaxed);
    sampler.join().expect("sampler");
    let peak_rss = peak.load(Ordering::Relaxed).max(rss(pid));

    std::thread::sleep(Duration::from_secs(3));
    let after_rss = rss(pid);

    let total = (CLIENTS * REQUESTS) as f64;
    let c = |a: &AtomicU64| a.load(Ordering::Relaxed);
    eprintln!(
        "load: {CLIENTS} clients x {REQUESTS} requests in {:.2} s = {:.0} requests/s; \
         normal: {} ok, {} errors; heavy: {} ok, {} got 503, {} errors",
        elapsed.as_secs_f64(),
        total / elapsed.as_secs_f64(),
        c(&counts.normal_ok),
        c(&counts.normal_errors),
        c(&counts.heavy_ok),
        c(&counts.heavy_503),
        c(&counts.heavy_errors),
    );
    eprintln!(
        "server rss: idle {} MB, peak {} MB (+{} MB), 3 s after {} MB (+{} MB)",
        idle_rss / MB,
        peak_rss / MB,
        peak_rss.saturating_sub(idle_rss) / MB,
        after_rss / MB,
        after_rss.saturating_sub(idle_rss) / MB,
    );
    for f in failures.iter().take(10) {
        eprintln!("failure: {f}");
    }

    // The idle connections: closed by the server once the idle timeout has passed.
    let wait = Duration::from_secs(IDLE_TIMEOUT_S + 2).saturating_sub(idle_opened.elapsed());
    std::thread::sleep(wait);
    let mut still_open = 0;
    for mut stream in idle {
        stream
            .set_read_timeout(Some(Duration::from_millis(200)))
            .expect("read timeout");
        let mut buf = [0u8; 4096];
        // Bounded: any bytes the server sends before closing (none expected) are skipped.
        for _ in 0..16 {
            match stream.read(&mut buf) {
                Ok(0) => break, // closed
                Ok(_) => continue,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    still_open += 1;
                    break;
                }
                Err(_) => break, // reset: closed
            }
        }
    }
    eprintln!(
        "idle connections: {} of {IDLE_CONNECTIONS} closed by the server",
        IDLE_CONNECTIONS - still_open
    );

    assert_eq!(
        c(&counts.normal_errors),
        0,
        "normal requests failed: {failures:?}"
    );
    assert_eq!(
        c(&counts.heavy_errors),
        0,
        "heavy requests failed: {failures:?}"
    );
    assert_eq!(
        c(&counts.normal_ok) + c(&counts.heavy_ok) + c(&counts.heavy_503),
        total as u64
    );
    assert!(
        peak_rss <= idle_rss + 512 * MB,
        "peak rss {} MB over idle {} MB + 512 MB",
        peak_rss / MB,
        idle_rss / MB
    );
    assert!(
        after_rss <= idle_rss + 64 * MB,
        "rss after the load {} MB over idle {} MB + 64 MB",
        after_rss / MB,
        idle_rss / MB
    );
    assert_eq!(
        still_open, 0,
        "idle connections left open after the idle timeout"
    );
    drop(server);
}

/// A short description of a failed request's outcome.
fn describe(outcome: &Result<(u16, Vec<u8>), String>) -> String {
    match outcome {
        Ok((status, body)) => format!(
            "status {status}, {} bytes: {}",
            body.len(),
            String::from_utf8_lossy(&body[..body.len().min(200)])
        ),
        Err(e) => format!("transport error: {e}"),
    }
}
