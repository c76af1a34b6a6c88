// The rig page in a real browser (scripts/web-test.sh): Debian's chromium,
// headless, driven by playwright-core. Arguments: the page's address, the
// daemon's token, a directory for screenshots, and the scenes the viewer
// is drawn in for comparison with `refl render`, as JSON: [{"name": ..,
// "camera": [POLAR, AZ], "light": [ELEV, AZ], "intensity": E}] (degrees;
// E the light's irradiance), each drawn to SHOTS/viewer-NAME.png.
// Prints one JSON object: the two captures' directories and what it saw.
const { chromium } = require("playwright-core");
const path = require("path");

const [base, token, shots, scenesArg] = process.argv.slice(2);
const scenes = JSON.parse(scenesArg);
const seen = {};

async function main() {
  const browser = await chromium.launch({
    executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
    args: [
      "--no-sandbox", "--disable-quic", "--no-first-run", "--disable-background-networking",
      "--disable-component-update", "--disable-sync",
      // WebGL without a GPU: SwiftShader, chromium's software renderer.
      "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
    ],
  });
  const page = await browser.newPage({ viewport: { width: 1200, height: 1100 } });
  // Waits, not time limits: a first capture calibrates the simulated rig
  // first, and a loaded 2-core machine takes its time.
  page.setDefaultTimeout(300000);
  const problems = [];
  page.on("pageerror", (e) => problems.push(`page error: ${e.message}`));
  // Every console error is a problem but the refusal the test asks for.
  let refusalExpected = false;
  page.on("console", (m) => {
    if (m.type() !== "error") return;
    if (refusalExpected && /status of 403/.test(m.text())) { refusalExpected = false; return; }
    problems.push(`console: ${m.text()}`);
  });
  // Clear the message line, then start: what follows is this start's answer.
  const start = async () => {
    await page.evaluate(() => { document.getElementById("msg").textContent = ""; });
    await page.click("#start");
  };
  await page.goto(base);
  await page.waitForFunction(() => document.getElementById("state").textContent === "idle");
  await page.waitForFunction(() => document.getElementById("samples").options.length > 0);

  // A wrong token is refused, and nothing starts.
  await page.fill("#token", "not-the-token");
  await page.fill("#sample", "satin");
  await page.selectOption("#quality", "fast");
  // Small and quick unless told otherwise (docs/ screenshots use a bigger one).
  await page.fill("#settings", process.env.FIRST_SETTINGS || "steps=12 grid=12 camera_px=64");
  refusalExpected = true;
  await start();
  await page.waitForFunction(() => document.getElementById("msg").textContent.startsWith("refused: 403"));
  seen.refused = await page.textContent("#msg");

  // The right one starts a capture; the page follows it.
  await page.fill("#token", token);
  await page.dispatchEvent("#token", "change");
  await start();
  await page.waitForFunction(() => document.getElementById("msg").textContent.startsWith("capturing into"));
  seen.first = (await page.textContent("#msg")).replace("capturing into ", "");
  // Progress advances: two different frame counts, the bar moving.
  const frames = () => page.evaluate(() => {
    const m = /^(\d+)\//.exec(document.getElementById("frames-text").textContent);
    return m ? Number(m[1]) : 0;
  });
  await page.waitForFunction(() => /^[1-9]\d*\//.test(document.getElementById("frames-text").textContent));
  const a = await frames();
  await page.waitForFunction((n) => {
    const m = /^(\d+)\//.exec(document.getElementById("frames-text").textContent);
    return m && Number(m[1]) > n;
  }, a);
  seen.frames = [a, await frames()];
  // The camera view arrives and is replaced by newer frames.
  await page.waitForFunction(() => /seq=\d+/.test(document.getElementById("frame").src));
  const src1 = await page.getAttribute("#frame", "src");
  await page.waitForFunction((s) => document.getElementById("frame").src.split("/").pop() !== s.split("/").pop(), src1);
  await page.waitForFunction(() => document.getElementById("frame").naturalWidth > 0);
  seen.frame_sources = [src1, await page.getAttribute("#frame", "src")];
  seen.frame_px = await page.evaluate(() => document.getElementById("frame").naturalWidth);
  await page.screenshot({ path: path.join(shots, "page-capturing.png") });
  // The end: the evaluation's table, the renders and the 3D viewer.
  await page.waitForFunction(() => document.querySelector("#eval table") !== null);
  await page.waitForFunction(() => window.reflectometerViewer && window.reflectometerViewer.drawn);
  seen.eval_rows = await page.evaluate(() => document.querySelectorAll("#eval table tr").length - 1);
  seen.renders = await page.evaluate(() => document.querySelectorAll("#renders img").length);
  seen.viewer_note = await page.textContent("#viewer-note");
  await page.screenshot({ path: path.join(shots, "page-result.png"), fullPage: true });

  // The viewer in the scenes `refl render` draws, 256 pixels square.
  for (const view of scenes) {
    await page.evaluate(async (view) => {
      const el = document.createElement("div");
      el.id = "compare";
      el.style.cssText = "position:fixed;left:0;top:0;width:256px;height:256px;z-index:10";
      document.body.appendChild(el);
      const v = await import("/viewer.js");
      await v.show("/result/gltf/material.gltf", el, view);
    }, view);
    await page.locator("#compare canvas").screenshot({ path: path.join(shots, `viewer-${view.name}.png`) });
    await page.evaluate(() => document.getElementById("compare").remove());
  }

  // Cancel a longer capture: it stops and leaves a resumable capture.
  await page.fill("#sample", "velvet");
  await page.fill("#settings", "steps=64 grid=12 camera_px=64");
  await start();
  await page.waitForFunction(() => document.getElementById("msg").textContent.startsWith("capturing into"));
  seen.cancelled = (await page.textContent("#msg")).replace("capturing into ", "");
  await page.waitForFunction(() => document.body.dataset.state === "capturing"
    && /^[1-9]\d*\//.test(document.getElementById("frames-text").textContent));
  await page.click("#cancel");
  await page.waitForFunction(() => document.getElementById("msg").textContent.startsWith("cancelling"));
  await page.waitForFunction(() => /exit 130/.test(document.getElementById("result-head").textContent));
  seen.cancel_result = await page.textContent("#result-head");
  seen.problems = problems;
  await browser.close();
  console.log(JSON.stringify(seen));
}

main().catch((e) => {
  console.error(`browser test failed: ${e.stack || e}\nseen so far: ${JSON.stringify(seen)}`);
  process.exit(1);
});
