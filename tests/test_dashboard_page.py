"""The dashboard page in a real headless Chromium, fed by recorded run files.

The run directory is built with the writers the roles use: eval.csv rows in the evaluator's
columns, learner.csv through the learner's MetricsLog, evaluation MCAPs by
``write_episode_mcap`` from real PyBullet observations, and a Q-attention snapshot computed
by the evaluator's snapshot code from a tiny randomly initialised C2FARM. The real app is
served by uvicorn on a free port; the RoleTable gets real Status messages.

Set C2FARM_UPDATE_SCREENSHOT=1 to refresh docs/dashboard.png from this test.
"""

from __future__ import annotations

import csv
import os
import shutil
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import httpx
import numpy as np
import pytest
import uvicorn
from conftest import REPO, get_free_port, wait_for

from dashboard.app import create_app
from dashboard.registry import RoleTable
from protocol.messages import Status

RUN_ID = "page-run"
T0 = time.time() - 3600.0  #: the recorded run was launched an hour ago
#: (weights_version, learner_step, env_steps, episodes, success_rate, unreachable_rate, seconds after launch)
EVALS = [(1, 0, 0, 10, 0.0, 0.2, 60), (3, 40, 120, 20, 0.1, 0.15, 300), (5, 80, 260, 20, 0.5, 0.05, 600),
         (7, 120, 400, 20, 0.85, 0.0, 900)]
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
#: Recording the run (torch, PyBullet, a tiny C2FARM) plus a browser can pass the suite's 300 s on a busy 2-core box.
pytestmark = pytest.mark.timeout(900)


def write_eval_csv(path: Path) -> None:
    from actors.evaluation import EVAL_FIELDS

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=EVAL_FIELDS)
        w.writeheader()
        for version, step, env_steps, episodes, success, unreachable, after in EVALS:
            w.writerow({"time": T0 + after, "weights_version": version, "learner_step": step, "env_steps": env_steps,
                        "episodes": episodes, "success_rate": success, "mean_return": 100 * success,
                        "unreachable_rate": unreachable})


def write_learner_csv(directory: Path) -> None:
    from learner.metrics import MetricsLog

    log = MetricsLog(directory)
    for step in range(10, 130, 10):
        log.write(step, {"loss/depth0": 1.0 / step, "loss/depth1": 2.0 / step, "q_chosen/depth0": step / 200,
                         "q_chosen/depth1": step / 300, "updates_per_s": 0.9, "samples_per_s": 7.3,
                         "replay_replay_size": 200 + 3 * step, "replay_samples_per_insert": 0.5 + step / 500})
    log.close()


def record_run(run: Path) -> dict:
    """A run directory as the roles would leave it; returns what the page should show."""
    import torch

    from actors.actor_loop import Rollout
    from actors.evaluation import write_snapshot
    from actors.panda_env import PandaEnv
    from actors.sim import SimConfig
    from protocol.attention_snapshot import FILENAME, load_snapshot
    from protocol.episode_file import write_episode_mcap
    from protocol.transition import pad_act_labels
    from qattention import C2FARM, ObservationBatch, QAttentionConfig
    from qattention.action_codec import encode_action

    (run / "config.yaml").write_text(
        f"run:\n  run_id: {RUN_ID}\nreplay:\n  capacity_transitions: 5000\n"
        "launch:\n  restart: [replay, learner, demo_source, actor, eval]\n  restart_backoff_max_s: 30\n"
        "  liveness_grace_s: 60\n")
    (run / "launched_at").write_text(str(T0))
    write_eval_csv(run / "metrics" / "eval.csv")
    write_learner_csv(run / "metrics")

    cameras = ("front", "wrist")
    env = PandaEnv(SimConfig(task="reach_target", cameras=cameras, image_size=64))
    try:
        config = QAttentionConfig(voxel_size=16, kernels=8, head_width=16, padding="zeros", bf16=False,
                                  cameras=cameras, scene_bounds=tuple(env.scene_bounds),
                                  episode_length=env.episode_length)
        with torch.random.fork_rng():
            agent = C2FARM(config, seed=0)
        # Episode 1: the scripted waypoint is executed (it reaches the target, and keeps the test
        # fast) and labelled as the actor labels what it executed, so the snapshot shows the
        # cascade zooming in on the target.
        first = env.reset(seed=1)
        executed = np.asarray(env.demo_waypoints()[0].action(), np.float32)
        labels = encode_action(
            torch.as_tensor(executed[None]), torch.as_tensor([env.scene_bounds], dtype=torch.float32), config
        )
        first.extras.update(
            voxel_indices=labels.voxel_indices[0].numpy(), attention_coordinates=labels.coordinates[0].numpy()
        )
        step = env.step(executed)
        frames = [first, step.observation]
        pad_act_labels(frames, config.depths)
        end = "success" if step.success else "failed"
        eval_dir = run / "eval"
        eval_dir.mkdir()
        write_episode_mcap(eval_dir / "v000007-seed1000000.mcap", frames, task="reach_target", seed=1000000,
                           success=bool(step.success), actions=[executed], end_reason=end)
        # Episode 2: ended on the agent's own (random-network) pose, reported unreachable.
        other = env.reset(seed=2)
        chosen = agent.act(ObservationBatch.from_observations([other], cameras)).action[0]
        write_episode_mcap(eval_dir / "v000007-seed1000001.mcap", [other, other], task="reach_target", seed=1000001,
                           success=False, actions=[chosen], end_reason="unreachable", unreachable_reason="ik_failed")
        # An older evaluation that must not be the one shown.
        write_episode_mcap(eval_dir / "v000005-seed1000000.mcap", [other], task="reach_target", seed=1000000,
                           success=False)
        # The snapshot as the evaluator writes it after an evaluation.
        write_snapshot(eval_dir, SimpleNamespace(agent=agent), Rollout(frames, actions=[executed], reason=end),
                       "reach_target", 1000000, SimpleNamespace(version=7, learner_step=120, env_steps=400))
        snapshot = load_snapshot(eval_dir / FILENAME)
    finally:
        env.close()
    return {"end": end, "executed": executed, "snapshot": snapshot}


def status(role: str, instance: str, state: str = "running", **counters) -> Status:
    return Status(role, instance, RUN_ID, 100, "lab-pc", time.time(), state, counters)


def feed(table: RoleTable) -> None:
    """What the run's roles would be saying: a learner, a replay, two actors, the evaluator, a finished demo source."""
    for s in (
        status("learner", "learner", updates=120, updates_per_s=0.9, weights_version=7),
        status("replay", "replay", size_transitions=560, samples_per_insert=0.74, ingest_rejected_decode=0),
        status("actor", "actor-0", episodes=60, env_steps=250, success_rate=0.3, unreachable_rate=0.1,
               weights_version=6, weights_latency_s=0.010035514831542969, sent=60, acked=60),
        status("actor", "actor-1", episodes=52, env_steps=150, success_rate=0.25, unreachable_rate=0.0,
               weights_version=7, weights_latency_s=0.2),
        status("eval", "eval", eval_success=0.85, eval_version=7, eval_unreachable=0.0, weights_version=7),
        status("demos", "demos", demos=10, demo_episodes=40),
    ):
        table.on_token(s.role, s.instance, True)
        table.on_status(s)
    table.on_status(status("demos", "demos", "stopped", demos=10, demo_episodes=40))  # finished its job
    table.on_token("demos", "demos", False)


class Heartbeats(threading.Thread):
    """Keeps the live roles' statuses fresh while the browser looks (they go stale after 3 s)."""

    def __init__(self, table: RoleTable) -> None:
        super().__init__(daemon=True)
        self.table, self.stop = table, threading.Event()

    def run(self) -> None:
        while not self.stop.wait(0.5):
            for r in self.table.snapshot()["roles"]:
                if r["role"] != "demos":
                    counters = dict(r["counters"])
                    if r["role"] == "actor":
                        counters["env_steps"] += 1  # acting at about 2 decisions per second
                    self.table.on_status(status(r["role"], r["instance"], **counters))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    run = tmp_path_factory.mktemp("runs") / RUN_ID
    run.mkdir()
    facts = record_run(run)
    return run, facts


@pytest.fixture(scope="module")
def served(recorded):
    """The real app on a real uvicorn for the recorded run; yields (base url, table)."""
    run, _ = recorded
    table = RoleTable(RUN_ID, gone_after_s=3.0)
    feed(table)
    beats = Heartbeats(table)
    beats.start()
    port = get_free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(table, refresh_ms=500, run_dir=run), host="127.0.0.1",
                                           port=port, log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        wait_for(lambda: server.started or not thread.is_alive(), 30, "uvicorn to start")
        yield f"http://127.0.0.1:{port}", table
    finally:
        beats.stop.set()
        server.should_exit = True
        thread.join(timeout=10)


def test_endpoints_serve_the_recorded_run(served, recorded):
    base, _ = served
    _, facts = recorded
    with httpx.Client(base_url=base, timeout=30) as client:
        history = client.get("/api/history")
        h = history.json()
        assert h["eval"]["series"]["env_steps"] == [e[2] for e in EVALS]
        assert h["eval"]["series"]["minutes"] == [e[6] / 60 for e in EVALS]
        assert h["replay_capacity"] == 5000 and h["learner"]["rows"] == 12
        assert h["learner"]["series"]["loss/depth1"][0] == pytest.approx(0.2)
        again = client.get("/api/history", headers={"If-None-Match": history.headers["etag"]})
        assert again.status_code == 304 and not again.content

        e = client.get("/api/episodes").json()
        assert e["weights_version"] == 7 and e["cameras"] == ["front", "wrist"]
        first, second = e["episodes"]
        assert (first["outcome"], second["outcome"], second["reason"]) == (facts["end"], "unreachable", "ik_failed")
        assert len(first["frames"]) == 2 and first["frames"][0]["action"] == pytest.approx(facts["executed"], abs=1e-4)
        assert first["frames"][0]["pose"]["front"]["in_view"]  # the reach waypoint is on the table, in front's view
        png = client.get(first["frames"][0]["images"]["front"])
        assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
        assert client.get("/api/episodes/frame/v000007-seed1000000.mcap/left_shoulder/0.png").status_code == 404

        q = client.get("/api/qattention").json()
        snap = facts["snapshot"]
        assert q["available"] and len(q["depths"]) == 2 and q["voxel_size"] == 16
        for d, depth in enumerate(q["depths"]):
            assert depth["occupied"]["count"] == len(snap.depths[d].occupied_index) > 0
            assert len(depth["occupied"]["centres"]) == 3 * depth["occupied"]["count"]
            assert len(depth["top"]["q"]) == 20 and depth["top"]["q"] == sorted(depth["top"]["q"], reverse=True)
        assert q["depths"][1]["bounds"][:3] == pytest.approx(np.asarray(q["depths"][0]["chosen"]["centre"]) - 0.15,
                                                             abs=1e-3)

        s = client.get("/api/status").json()
        words = {r["instance"]: r["state_word"] for r in s["roles"]}
        assert words["demos"] == "finished" and words["actor-0"] == "running"


def _driver(width: int = 1400, height: int = 1000):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={width},{height}",
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
                 "--hide-scrollbars", "--force-device-scale-factor=1"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)


READY = """
const c = window.c2farm;
return Boolean(c && c.polls && c.polls.status > 1 && c.polls.history && c.polls.episodes && c.qattention
  && c.qattention.rendered && c.charts["eval-steps"] && document.querySelectorAll("#actor-rows tr[data-role]").length
  && [...document.querySelectorAll("#episodes img")].every(i => i.complete && i.naturalWidth > 0));
"""

#: Pixels of a canvas that differ from its background colour (#f8fafc), read back through a 2D canvas.
INK = """
const src = document.getElementById(arguments[0]);
const c = document.createElement("canvas"); c.width = src.width; c.height = src.height;
const g = c.getContext("2d"); g.drawImage(src, 0, 0);
const d = g.getImageData(0, 0, c.width, c.height).data;
let ink = 0;
for (let i = 0; i < d.length; i += 4) if (Math.abs(d[i] - 248) + Math.abs(d[i + 1] - 250) + Math.abs(d[i + 2] - 252) >
30) ink++;
return [ink, c.width * c.height];
"""


def test_the_page_in_headless_chromium(served, tmp_path):
    missing = [path for path in (CHROMIUM, CHROMEDRIVER) if not os.path.exists(path)]
    assert not missing, f"{missing} missing: install Debian's chromium and chromium-driver (.ci/run does)"
    from selenium.webdriver.support.ui import WebDriverWait

    base, _ = served
    driver = _driver()
    try:
        driver.get(base + "/")
        WebDriverWait(driver, 120, poll_frequency=0.5).until(lambda d: d.execute_script(READY))

        severe = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        assert not severe, severe

        chart = driver.execute_script("return window.c2farm.charts['eval-steps'].data")
        assert chart[0] == [e[2] for e in EVALS]
        assert chart[1] == pytest.approx([100 * e[4] for e in EVALS])
        timeline = driver.execute_script("return window.c2farm.charts['eval-time'].data")
        assert timeline[0] == pytest.approx([e[6] / 60 for e in EVALS])

        rows = driver.execute_script("""return [...document.querySelectorAll('#actor-rows tr[data-role]')]
            .map(r => [r.dataset.instance, r.querySelector('.state').textContent, r.cells[3].textContent,
            r.cells[8].textContent])""")
        by_name = {r[0]: r[1:] for r in rows}
        assert set(by_name) == {"actor-0", "actor-1", "eval", "demos"}
        assert by_name["actor-0"] == ["running", "1", "10 ms"]  # lag 7 - 6, latency rounded for people
        assert by_name["demos"][0] == "finished"
        text = driver.find_element("tag name", "body").text
        assert "0.010035514831542969" not in driver.page_source
        assert driver.execute_script("return document.getElementById('roles').open") is False

        views = driver.execute_script("return window.c2farm.qattention.views")
        assert [v["depth"] for v in views] == [0, 1] and all(v["meshes"] >= 5 and v["voxels"] > 0 for v in views)
        for d in (0, 1):
            ink, total = driver.execute_script(INK, f"q-depth-{d}")
            assert ink > 0.01 * total, f"depth {d}: the 3D view is blank ({ink} of {total} pixels drawn)"

        episodes = driver.find_elements("css selector", "#episodes .episode")
        assert len(episodes) == 2 and "unreachable" in text and "ik failed" in text
        assert driver.find_elements("css selector", "#episodes svg.pose circle")

        height = driver.execute_script("return document.documentElement.scrollHeight")
        driver.set_window_size(1400, min(height + 40, 4000))
        time.sleep(1.0)  # charts and 3D views redraw at the new size
        shot = tmp_path / "dashboard.png"
        driver.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
        if os.environ.get("C2FARM_UPDATE_SCREENSHOT"):
            shutil.copy(shot, REPO / "docs" / "dashboard.png")
    finally:
        driver.quit()
