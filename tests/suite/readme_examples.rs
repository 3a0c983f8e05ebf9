//! README.md's shell examples, run as written (issue 16): every command line of every fenced
//! `sh` block runs through `bash`, in README order, in a scratch copy of the repository's files,
//! with `raypick` on the `PATH` (this build's binary) and `cargo run --release -- ARGS` running
//! it with ARGS. A non-zero exit, a panic or a line running past its time fails the test. Lines
//! ending in `# long run` are skipped (and counted); a line ending in `&` starts a server that
//! the block's next lines talk to (on a free port instead of the README's 8080), stopped when
//! the block ends.
//!
//! The pictures the README's `render` lines write into `docs/` must come out pixel for pixel as
//! the committed ones, and every picture in `docs/` must be made by such a line.
//!
//! The README's Rust example is a doctest (`src/lib.rs` includes README.md under
//! `cfg(doctest)`), so `cargo test --doc` compiles and runs it.

use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The marker of README lines the test skips.
const LONG_RUN: &str = "# long run";

/// The longest one README line may run.
const LINE_LIMIT: Duration = Duration::from_secs(120);

/// One fenced `sh` block: its first line number in README.md and its commands.
struct Block {
    line: usize,
    commands: Vec<Line>,
}

/// One command: its README line number and its text (continuation lines joined, a heredoc's
/// lines kept).
struct Line {
    line: usize,
    text: String,
}

/// The `sh` blocks of `readme`, split into commands: lines ending in `\` continue on the next
/// line; a line with `<<'TAG'` (or `<<TAG`) takes the lines up to `TAG` as its heredoc; blank
/// lines and comment lines are left out.
fn sh_blocks(readme: &str) -> Vec<Block> {
    let mut blocks = Vec::new();
    let mut lines = readme.lines().enumerate().map(|(i, l)| (i + 1, l));
    while let Some((at, line)) = lines.next() {
        if line.trim() != "```sh" {
            continue;
        }
        let mut block = Block {
            line: at,
            commands: Vec::new(),
        };
        let mut pending: Option<Line> = None;
        while let Some((n, line)) = lines.next() {
            if line.trim() == "```" {
                break;
            }
            let mut command = match pending.take() {
                Some(mut c) => {
                    c.text.push(' ');
                    c.text.push_str(line.trim_start());
                    c
                }
                None if line.trim().is_empty() || line.trim_start().starts_with('#') => continue,
                None => Line {
                    line: n,
                    text: line.to_string(),
                },
            };
            if command.text.ends_with('\\') {
                command.text.pop();
                pending = Some(command);
                continue;
            }
            if let Some(tag) = heredoc_tag(&command.text) {
                for (_, body) in lines.by_ref() {
                    command.text.push('\n');
                    command.text.push_str(body);
                    if body.trim() == tag {
                        break;
                    }
                }
            }
            block.commands.push(command);
        }
        assert!(pending.is_none(), "README.md:{at}: a block ends with `\\`");
        blocks.push(block);
    }
    blocks
}

/// The end tag of a heredoc started on `line` (`<<'TAG'`, `<<"TAG"` or `<<TAG`).
fn heredoc_tag(line: &str) -> Option<String> {
    let rest = line.split("<<").nth(1)?.trim_start();
    let tag: String = rest
        .trim_start_matches(['\'', '"'])
        .chars()
        .take_while(|c| c.is_alphanumeric() || *c == '_')
        .collect();
    (!tag.is_empty()).then_some(tag)
}

/// Copies the repository's files (everything but `target` folders and `.git`) to `to`.
fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let name = entry.file_name();
        if name == "target" || name == ".git" {
            continue;
        }
        let kind = entry.file_type().unwrap();
        if kind.is_dir() {
            copy_tree(&entry.path(), &to.join(&name));
        } else if kind.is_file() {
            std::fs::copy(entry.path(), to.join(&name)).unwrap();
        }
    }
}

/// A scratch folder, removed when dropped.
struct Scratch(PathBuf);

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Makes `bin/raypick` (this build's binary) and `bin/cargo` (which runs `cargo run --release
/// -- ARGS` as `raypick ARGS` and refuses anything else) in `dir`.
fn shims(dir: &Path) -> PathBuf {
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_raypick"), bin.join("raypick")).unwrap();
    let cargo = bin.join("cargo");
    std::fs::write(
        &cargo,
        "#!/bin/sh\n\
         if [ \"$1\" = run ] && [ \"$2\" = --release ] && [ \"$3\" = -- ]; then\n\
         \tshift 3\n\
         \texec raypick \"$@\"\n\
         fi\n\
         echo \"the README test runs only 'cargo run --release -- ARGS'; mark this line '# long run'\" >&2\n\
         exit 99\n",
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&cargo, std::fs::Permissions::from_mode(0o755)).unwrap();
    bin
}

/// A `bash -c text` command in `dir` with `bin` first on the `PATH`.
fn bash(text: &str, dir: &Path, bin: &Path) -> Command {
    let mut command = Command::new("bash");
    command
        .args(["-c", text])
        .current_dir(dir)
        .env(
            "PATH",
            format!(
                "{}:{}",
                bin.display(),
                std::env::var("PATH").unwrap_or_default()
            ),
        )
        // The Vulkan loader complains without a runtime folder.
        .env("XDG_RUNTIME_DIR", dir)
        .stdin(Stdio::null());
    command
}

/// Runs one README command to its end (at most [`LINE_LIMIT`]) and fails the test on a non-zero
/// exit or a panic; returns its standard output.
fn run_line(command: &Line, dir: &Path, bin: &Path) -> String {
    let out_path = dir.join(".readme-test-stdout");
    let err_path = dir.join(".readme-test-stderr");
    let mut child = bash(&command.text, dir, bin)
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("run bash");
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > LINE_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "README.md:{}: still running after {LINE_LIMIT:?} (mark it '{LONG_RUN}'?):\n{}",
                command.line, command.text
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let stdout = std::fs::read_to_string(&out_path).unwrap_or_default();
    let stderr = std::fs::read_to_string(&err_path).unwrap_or_default();
    let shown = |text: &str| text.chars().take(3000).collect::<String>();
    // curl exits 0 on an HTTP error too; the server's errors are `{"error": "sentence"}`.
    let http_error = command.text.starts_with("curl") && stdout.contains("{\"error\"");
    assert!(
        status.success() && !stderr.contains("panicked") && !http_error,
        "README.md:{}: {status}\n$ {}\n--- stdout\n{}\n--- stderr\n{}",
        command.line,
        command.text,
        shown(&stdout),
        shown(&stderr)
    );
    eprintln!(
        "README.md:{}: ok ({:.1} s): {}",
        command.line,
        start.elapsed().as_secs_f64(),
        command.text.lines().next().unwrap_or_default()
    );
    stdout
}

/// The answers the README quotes after its curl session (each `{…}` span in the paragraph that
/// begins "The first `/pick` answers") must be what one of the session's curl commands printed:
/// the span's text up to its first "…" begins that command's output, and each later piece that
/// holds JSON punctuation lies in it. A quoted answer once said the terrain was hit where the
/// server answered the tower's roof.
fn check_quoted_answers(readme: &str, served: &[String]) {
    let start = readme
        .find("The first `/pick` answers")
        .expect("the README describes its curl session's answers");
    let paragraph = &readme[start..];
    let paragraph = &paragraph[..paragraph.find("\n\n").unwrap_or(paragraph.len())];
    let spans: Vec<&str> = paragraph
        .split('`')
        .skip(1)
        .step_by(2)
        .filter(|span| span.starts_with('{'))
        .collect();
    for span in &spans {
        let mut pieces = span.split('…');
        let first = pieces.next().unwrap_or_default();
        let rest: Vec<&str> = pieces
            .filter(|p| p.contains(['"', ':', '}', ']']))
            .collect();
        assert!(
            served
                .iter()
                .any(|out| out.starts_with(first) && rest.iter().all(|p| out.contains(p))),
            "README.md quotes the answer {span}; the curl commands printed:\n{}",
            served.join("\n").chars().take(3000).collect::<String>()
        );
    }
    assert!(
        spans.len() >= 4,
        "only {} quoted answers found",
        spans.len()
    );
}

/// Starts a README command that ends in `&` (a server) and waits until `addr` takes
/// connections.
fn start_server(command: &Line, dir: &Path, bin: &Path, addr: SocketAddr) -> Child {
    let text = command.text.trim_end().trim_end_matches('&');
    let mut child = bash(&format!("exec {text}"), dir, bin)
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start the server");
    let start = Instant::now();
    while TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_err() {
        if let Some(status) = child.try_wait().unwrap() {
            panic!(
                "README.md:{}: the server exited ({status}) before listening on {addr}",
                command.line
            );
        }
        assert!(
            start.elapsed() < LINE_LIMIT,
            "README.md:{}: no server on {addr} after {LINE_LIMIT:?}",
            command.line
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    child
}

/// A TCP port on 127.0.0.1 that was free a moment ago.
fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The RGBA pixels and size of a PNG.
fn pixels(path: &Path) -> (u32, u32, Vec<u8>) {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut buffer = vec![0; reader.output_buffer_size().expect("a PNG of sane size")];
    let info = reader.next_frame(&mut buffer).unwrap();
    buffer.truncate(info.buffer_size());
    assert_eq!(
        (info.color_type, info.bit_depth),
        (png::ColorType::Rgba, png::BitDepth::Eight),
        "{}",
        path.display()
    );
    (info.width, info.height, buffer)
}

#[test]
fn the_readme_shell_examples_run_as_written() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(repo.join("README.md")).unwrap();
    let blocks = sh_blocks(&readme);
    assert!(blocks.len() >= 10, "{} sh blocks found", blocks.len());
    let scratch = Scratch(std::env::temp_dir().join(format!(
        "raypick-readme-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos()
    )));
    let dir = scratch.0.join("repo");
    copy_tree(repo, &dir);
    let bin = shims(&scratch.0);
    let (mut ran, mut skipped) = (0, Vec::new());
    let mut served = Vec::new();
    for block in &blocks {
        let mut servers: Vec<Child> = Vec::new();
        // The README's servers listen on 8080; here on a free port, in every line of the block.
        let port = free_port();
        for command in &block.commands {
            if command.text.trim_end().ends_with(LONG_RUN) {
                skipped.push(command.line);
                continue;
            }
            let command = Line {
                line: command.line,
                text: command
                    .text
                    .replace("127.0.0.1:8080", &format!("127.0.0.1:{port}")),
            };
            if command.text.trim_end().ends_with('&') {
                let addr: SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
                assert!(
                    command.text.contains(&addr.to_string()),
                    "README.md:{}: a server line must say --addr 127.0.0.1:8080",
                    command.line
                );
                servers.push(start_server(&command, &dir, &bin, addr));
            } else {
                let stdout = run_line(&command, &dir, &bin);
                if command.text.starts_with("curl") {
                    served.push(stdout);
                }
            }
            ran += 1;
        }
        for mut server in servers {
            let _ = server.kill();
            let _ = server.wait();
        }
        assert!(
            !block.commands.is_empty(),
            "README.md:{}: an empty sh block",
            block.line
        );
    }
    check_quoted_answers(&readme, &served);
    eprintln!(
        "{ran} README command lines ran; skipped as long runs: lines {skipped:?} of README.md"
    );
    assert!(ran >= 30, "only {ran} README lines ran");

    // The pictures in docs/: each is made by a README line, and comes out as committed.
    for entry in std::fs::read_dir(repo.join("docs")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "png") {
            continue;
        }
        let name = path.file_name().unwrap().to_str().unwrap().to_string();
        assert!(
            readme.contains(&format!("--out docs/{name}")),
            "docs/{name} is made by no README command"
        );
        let (committed, made) = (pixels(&path), pixels(&dir.join("docs").join(&name)));
        assert_eq!(
            (committed.0, committed.1),
            (made.0, made.1),
            "docs/{name}: size"
        );
        let differing = committed
            .2
            .chunks(4)
            .zip(made.2.chunks(4))
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(
            differing, 0,
            "docs/{name}: {differing} pixels differ from what the README's command makes now; \
             run that command to regenerate it"
        );
    }
}

#[test]
fn the_readme_parser_joins_continuations_and_heredocs() {
    let readme = "text\n```sh\n# a comment\nraypick a \\\n  --b c   # note\n\ncat > f <<'JSON'\n{\"x\": 1}\nJSON\nraypick d  # long run\n```\n```text\nnot run\n```\n";
    let blocks = sh_blocks(readme);
    assert_eq!(blocks.len(), 1);
    let texts: Vec<&str> = blocks[0].commands.iter().map(|c| c.text.as_str()).collect();
    assert_eq!(
        texts,
        [
            "raypick a  --b c   # note",
            "cat > f <<'JSON'\n{\"x\": 1}\nJSON",
            "raypick d  # long run"
        ]
    );
    assert_eq!(blocks[0].commands[1].line, 7);
}
