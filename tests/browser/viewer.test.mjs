// Browser test of the `raypick serve` viewer page, in headless Chromium driven over WebDriver by
// Debian's chromedriver. No npm packages: Node's own test runner, fetch and child_process.
//
// Run by .ci/browser-test, which starts the server. Environment:
//   RAYPICK_URL   the server's base URL, e.g. http://127.0.0.1:41234/ (required)
//   BROWSER_OUT   where screenshots go (default target/browser)
//   CHROMIUM      the browser binary (default /usr/bin/chromium)
//   CHROMEDRIVER  the driver binary (default /usr/bin/chromedriver)
//
// Steps: open the page, wait for the rendered image, take a screenshot, click the image's
// centre and check the pick result names an object and a world position, drag and check the
// camera orbited and a new image loaded, wheel and check the camera zoomed out.

import { test } from "node:test";
import assert from "node:assert/strict";
import { spawn } from "node:child_process";
import { mkdtempSync, mkdirSync, rmSync, writeFileSync } from "node:fs";
import { createServer } from "node:net";
import { tmpdir } from "node:os";
import { join } from "node:path";

const BASE = process.env.RAYPICK_URL;
const OUT = process.env.BROWSER_OUT || "target/browser";
const CHROMIUM = process.env.CHROMIUM || "/usr/bin/chromium";
const CHROMEDRIVER = process.env.CHROMEDRIVER || "/usr/bin/chromedriver";
const ELEMENT = "element-6066-11e4-a52e-4f735466cecf";

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

/** A free loopback port. */
function freePort() {
  return new Promise((resolve, reject) => {
    const server = createServer();
    server.unref();
    server.on("error", reject);
    server.listen(0, "127.0.0.1", () => {
      const { port } = server.address();
      server.close(() => resolve(port));
    });
  });
}

/** A minimal W3C WebDriver client. */
class Driver {
  constructor(port) {
    this.base = `http://127.0.0.1:${port}`;
    this.session = null;
  }

  /** `method` on the driver's `path` (absolute, e.g. `/status`). */
  async call(method, path, body) {
    const response = await fetch(`${this.base}${path}`, {
      method,
      headers: { "content-type": "application/json" },
      body: body === undefined ? undefined : JSON.stringify(body),
    });
    const answer = await response.json();
    if (!response.ok) {
      const v = answer.value || {};
      throw new Error(`WebDriver ${method} ${path}: ${v.error}: ${v.message}`);
    }
    return answer.value;
  }

  /** `method` on the session's `path` (e.g. `/url`). */
  in(method, path, body) {
    return this.call(method, `/session/${this.session}${path}`, body);
  }

  async start(userDataDir) {
    const value = await this.call("POST", "/session", {
      capabilities: {
        alwaysMatch: {
          browserName: "chrome",
          "goog:loggingPrefs": { browser: "ALL" },
          "goog:chromeOptions": {
            binary: CHROMIUM,
            args: [
              "--headless",
              "--no-sandbox",
              "--disable-gpu",
              "--disable-quic",
              "--no-first-run",
              "--disable-background-networking",
              "--disable-component-update",
              "--disable-sync",
              "--disable-dev-shm-usage",
              "--window-size=1280,800",
              `--user-data-dir=${userDataDir}`,
            ],
          },
        },
      },
    });
    this.session = value.sessionId;
  }

  async stop() {
    if (this.session) {
      const id = this.session;
      this.session = null;
      await this.call("DELETE", `/session/${id}`).catch(() => {});
    }
  }

  navigate(url) { return this.in("POST", "/url", { url }); }
  run(script, ...args) { return this.in("POST", "/execute/sync", { script, args }); }
  async find(css) {
    const value = await this.in("POST", "/element", { using: "css selector", value: css });
    return { [ELEMENT]: value[ELEMENT] };
  }
  actions(actions) { return this.in("POST", "/actions", { actions }); }
  async screenshot(path) {
    const png = Buffer.from(await this.in("GET", "/screenshot"), "base64");
    writeFileSync(path, png);
    return png;
  }
  async browserLog() {
    try {
      return await this.in("POST", "/se/log", { type: "browser" });
    } catch {
      return [];
    }
  }

  /** Polls `script` until it returns a truthy value; returns it. */
  async until(what, script, timeoutMs = 60000) {
    const deadline = Date.now() + timeoutMs;
    let last;
    while (Date.now() < deadline) {
      last = await this.run(script);
      if (last) return last;
      await sleep(100);
    }
    throw new Error(`timed out after ${timeoutMs} ms waiting for ${what} (last: ${JSON.stringify(last)})`);
  }
}

const state = `return {
  renders: window.viewer.renders, picks: window.viewer.picks, loading: document.getElementById("busy").style.display === "block",
  src: document.getElementById("view").getAttribute("src"), camera: window.viewer.shown,
  natural: [document.getElementById("view").naturalWidth, document.getElementById("view").naturalHeight],
  complete: document.getElementById("view").complete }`;

const distance = (camera) => {
  const p = camera.perspective;
  return Math.hypot(p.eye[0] - p.target[0], p.eye[1] - p.target[1], p.eye[2] - p.target[2]);
};

test("raypick viewer in headless Chromium", { timeout: 300000 }, async (t) => {
  assert.ok(BASE, "RAYPICK_URL must name the running server");
  mkdirSync(OUT, { recursive: true });
  const port = await freePort();
  const driverProcess = spawn(CHROMEDRIVER, [`--port=${port}`, "--allowed-ips=127.0.0.1"], {
    stdio: ["ignore", "ignore", "inherit"],
  });
  const userDataDir = mkdtempSync(join(tmpdir(), "raypick-chromium-"));
  const driver = new Driver(port);
  try {
    // Wait for the driver.
    const deadline = Date.now() + 30000;
    for (;;) {
      try {
        const status = await driver.call("GET", "/status");
        if (status.ready) break;
      } catch { /* not up yet */ }
      if (Date.now() > deadline) throw new Error("chromedriver did not start");
      await sleep(100);
    }
    await driver.start(userDataDir);

    await t.test("the page loads and shows the rendered view", async () => {
      await driver.navigate(BASE);
      await driver.until("the first image", `return window.viewer && window.viewer.ready &&
        document.getElementById("view").complete && document.getElementById("view").naturalWidth > 0`);
      const s = await driver.run(state);
      assert.deepEqual(s.natural, [s.camera.perspective.width, s.camera.perspective.height]);
      assert.match(s.src, /^\/render\?shade=normal&version=\d+&camera=/);
      const info = await driver.run(`return document.getElementById("scene-info").textContent`);
      assert.match(info, /triangles/);
      const png = await driver.screenshot(join(OUT, "screenshot.png"));
      assert.equal(png.subarray(1, 4).toString(), "PNG");
      console.log(`screenshot: ${join(OUT, "screenshot.png")} (${png.length} bytes); scene: ${info}`);
    });

    const image = await driver.find("#view");

    await t.test("a click picks the pixel and shows object and position", async () => {
      await driver.actions([{
        type: "pointer", id: "mouse", parameters: { pointerType: "mouse" },
        actions: [
          { type: "pointerMove", duration: 0, origin: image, x: 0, y: 0 },
          { type: "pointerDown", button: 0 },
          { type: "pointerUp", button: 0 },
        ],
      }]);
      await driver.until("the pick result", `return window.viewer.picks >= 1`);
      const text = await driver.run(`return document.getElementById("pick-result").innerText`);
      console.log(`pick result:\n${text}`);
      assert.match(text, /object\s+\d+ \([^)]+\)/);
      const number = String.raw`-?\d+(?:\.\d+)?(?:e[-+]?\d+)?`;
      assert.match(text, new RegExp(String.raw`position\s+${number}, ${number}, ${number}`));
      const hit = await driver.run(`return window.viewer.lastPick`);
      assert.equal(hit.hit, true);
      assert.equal(typeof hit.object, "number");
      // The page shows the position exactly as the server sent it (shortest round-trip form).
      const shown = await driver.run(`return document.getElementById("pick-position").textContent`);
      assert.equal(shown, hit.position.map(String).join(", "));
      // The same pick through the API directly gives the same answer.
      const s = await driver.run(state);
      const px = await driver.run(`return window.viewer.lastPixel`);
      assert.ok(Math.abs(px[0] - s.natural[0] / 2) <= 1 && Math.abs(px[1] - s.natural[1] / 2) <= 1,
        `the centre pixel was picked: ${px}`);
      const direct = await (await fetch(new URL("/pick", BASE), {
        method: "POST",
        body: JSON.stringify({ camera: s.camera, pixels: [px] }),
      })).json();
      assert.deepEqual(direct.results[0], hit);
      await driver.screenshot(join(OUT, "screenshot-pick.png"));
    });

    await t.test("a drag orbits the camera and loads a new image", async () => {
      const before = await driver.run(state);
      const moves = [];
      for (let i = 0; i < 8; i += 1) {
        moves.push({ type: "pointerMove", duration: 30, origin: "pointer", x: 15, y: 4 });
      }
      await driver.actions([{
        type: "pointer", id: "mouse", parameters: { pointerType: "mouse" },
        actions: [
          { type: "pointerMove", duration: 0, origin: image, x: -60, y: 0 },
          { type: "pointerDown", button: 0 },
          ...moves,
          { type: "pointerUp", button: 0 },
        ],
      }]);
      const after = await driver.until("the orbited image", `const s = (() => { ${state} })();
        return !s.loading && s.renders > ${before.renders} && s.src !== ${JSON.stringify(before.src)} ? s : null`);
      assert.notDeepEqual(after.camera.perspective.eye, before.camera.perspective.eye);
      assert.deepEqual(after.camera.perspective.target, before.camera.perspective.target);
      // Orbiting keeps the distance to the target.
      assert.ok(Math.abs(distance(after.camera) - distance(before.camera)) < 1e-9 * distance(before.camera));
      assert.equal(await driver.run(`return window.viewer.picks`), 1, "a drag is not a click");
      await driver.screenshot(join(OUT, "screenshot-orbit.png"));
    });

    await t.test("the wheel zooms out and loads a new image", async () => {
      const before = await driver.run(state);
      await driver.actions([{
        type: "wheel", id: "wheel",
        actions: [{ type: "scroll", duration: 0, origin: image, x: 0, y: 0, deltaX: 0, deltaY: 300 }],
      }]);
      const after = await driver.until("the zoomed image", `const s = (() => { ${state} })();
        return !s.loading && s.renders > ${before.renders} && s.src !== ${JSON.stringify(before.src)} ? s : null`);
      assert.ok(distance(after.camera) > distance(before.camera) * 1.05,
        `the eye moved away: ${distance(before.camera)} -> ${distance(after.camera)}`);
      await driver.screenshot(join(OUT, "screenshot-zoom.png"));
    });

    await t.test("a click selects a building and a shift-drag moves it over the terrain", async () => {
      const s = await driver.run(state);
      const [w, h] = s.natural;
      const shownWidth = await driver.run(`return document.getElementById("view").getBoundingClientRect().width`);
      const k = shownWidth / w;
      // A pixel on the tower (object 1), found through the API with the camera on screen.
      const grid = [];
      for (let y = 4; y < h; y += 8) for (let x = 4; x < w; x += 8) grid.push([x, y]);
      const found = await (await fetch(new URL("/pick", BASE), {
        method: "POST",
        body: JSON.stringify({ camera: s.camera, pixels: grid }),
      })).json();
      const on = grid.map((px, i) => [px, found.results[i]]).filter(([, r]) => r.hit && r.object === 1);
      assert.ok(on.length > 0, "the tower is in view");
      const [[px, py], before] = on[Math.floor(on.length / 2)];
      const at = (x, y) => ({ x: Math.round((x + 0.5 - w / 2) * k), y: Math.round((y + 0.5 - h / 2) * k) });
      const start = at(px, py);
      const picksBefore = await driver.run(`return window.viewer.picks`);
      await driver.actions([{
        type: "pointer", id: "mouse", parameters: { pointerType: "mouse" },
        actions: [
          { type: "pointerMove", duration: 0, origin: image, x: start.x, y: start.y },
          { type: "pointerDown", button: 0 },
          { type: "pointerUp", button: 0 },
        ],
      }]);
      await driver.until("the selection", `return window.viewer.picks > ${picksBefore} && window.viewer.selected`);
      assert.equal(await driver.run(`return window.viewer.selected.object`), 1);
      // Shift held: the drag moves the tower instead of orbiting.
      const steps = 8;
      const moves = [];
      for (let i = 0; i < steps; i += 1) {
        moves.push({ type: "pointerMove", duration: 60, origin: "pointer", x: Math.round(-90 / steps), y: 0 });
      }
      const pointer = [
        { type: "pointerMove", duration: 0, origin: image, x: start.x, y: start.y },
        { type: "pointerDown", button: 0 },
        ...moves,
        { type: "pause", duration: 300 },
        { type: "pointerUp", button: 0 },
        { type: "pause", duration: 0 },
      ];
      const keys = [{ type: "keyDown", value: "\uE008" }];
      while (keys.length < pointer.length - 1) keys.push({ type: "pause", duration: 0 });
      keys.push({ type: "keyUp", value: "\uE008" });
      const rendersBefore = s.renders;
      await driver.actions([
        { type: "key", id: "keyboard", actions: keys },
        { type: "pointer", id: "mouse", parameters: { pointerType: "mouse" }, actions: pointer },
      ]);
      await driver.until("the move and the new image", `const s = (() => { ${state} })();
        return window.viewer.moves >= 1 && !s.loading && s.renders > ${rendersBefore} ? s : null`);
      const after = await driver.run(state);
      assert.deepEqual(after.camera, s.camera, "a move is not an orbit");
      // The server has the new transform; the picks follow the tower.
      const scene = await (await fetch(new URL("/scene", BASE))).json();
      const tower = scene.objects.find((o) => o.id === 1);
      assert.ok(tower.transform, "the tower has a transform");
      const d = tower.transform.map((row) => row[3]);
      assert.ok(Math.hypot(d[0], d[1]) > 1, `the tower moved: ${d}`);
      const eye = s.camera.perspective.eye;
      const p = before.position;
      const dir = [p[0] - eye[0], p[1] - eye[1], p[2] - eye[2]];
      const ray = { origin: [eye[0] + d[0], eye[1] + d[1], eye[2] + d[2]], dir };
      const followed = await (await fetch(new URL("/pick", BASE), {
        method: "POST",
        body: JSON.stringify({ rays: [ray], mode: "all", max_hits: 64 }),
      })).json();
      const moved = followed.results[0].hits.find((hit) => hit.object === 1);
      assert.ok(moved, "the moved ray meets the tower");
      const expected = [p[0] + d[0], p[1] + d[1], p[2] + d[2]];
      assert.ok(Math.hypot(...moved.position.map((x, i) => x - expected[i])) < 1e-6,
        `the tower's point moved with it: ${moved.position} vs ${expected}`);
      await driver.screenshot(join(OUT, "screenshot-move.png"));
    });

    await t.test("the page logged no errors", async () => {
      const log = await driver.browserLog();
      const severe = log.filter((e) => e.level === "SEVERE");
      assert.deepEqual(severe, []);
    });
  } finally {
    await driver.stop();
    driverProcess.kill();
    rmSync(userDataDir, { recursive: true, force: true });
  }
});
