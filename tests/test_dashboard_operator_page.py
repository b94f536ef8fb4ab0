"""The operator's buttons on the dashboard page, pressed in a real headless Chromium.

The real app runs on uvicorn, its RoleTable fed real Status messages. The dashboard's operator
publisher and a robot actor's ``FabricOperator`` each have a real Zenoh session on a real
router, so a click travels page -> HTTP -> Zenoh -> the robot actor's operator channel. A command
needs the dashboard's token (dashboard/access.py): the page takes it from its URL (``?token=``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import threading
import time

import pytest
import uvicorn
from conftest import get_free_port, wait_for
from test_dashboard_page import CHROMEDRIVER, CHROMIUM, _driver

from actors.robot.operator import FabricOperator, OperatorChannel
from dashboard.app import create_app
from dashboard.operator_buttons import OperatorPublisher
from dashboard.registry import RoleTable
from protocol.fabric import open_session
from protocol.messages import OperatorAction, Status

pytestmark = pytest.mark.timeout(600)
RUN_ID = "operator-page"
NEVER = threading.Event()
TOKEN = "page-test-token-5kq2VbL0wX8dR1"

#: The page has polled the status twice: whatever it shows reflects the roles fed to it.
POLLED = "return Boolean(window.c2farm && window.c2farm.polls.status > 1)"


@pytest.fixture
def shm() -> bool:
    return False  # the router fixture's transport does not matter here: one run, not both


@pytest.fixture(autouse=True)
def chromium_installed():
    missing = [path for path in (CHROMIUM, CHROMEDRIVER) if not os.path.exists(path)]
    assert not missing, f"{missing} missing: install Debian's chromium and chromium-driver (.ci/run does)"


def running(role: str, instance: str, info: dict | None = None, **counters) -> Status:
    return Status(role, instance, RUN_ID, 100, "lab-pc", time.time(), "running", counters, info or {})


class Roles(threading.Thread):
    """A RoleTable fed by these roles, saying they are alive every 0.5 s (statuses go stale after 3 s)."""

    def __init__(self, *statuses: Status) -> None:
        super().__init__(daemon=True)
        self.statuses, self.stop = statuses, threading.Event()
        self.table = RoleTable(RUN_ID, gone_after_s=3.0)
        for s in statuses:
            self.table.on_token(s.role, s.instance, True)
            self.table.on_status(s)

    def run(self) -> None:
        while not self.stop.wait(0.5):
            for s in self.statuses:
                self.table.on_status(dataclasses.replace(s, time=time.time()))


@contextlib.contextmanager
def page(roles: Roles, path: str = f"/?token={TOKEN}", host: str = "127.0.0.1", fabric: str = "loopback"):
    """(app, browser on its page, base URL): the app (token :data:`TOKEN`) on a real uvicorn bound to ``host``,
    showing ``roles``; the browser opens ``path`` at 127.0.0.1."""
    roles.start()
    app = create_app(roles.table, refresh_ms=300, token=TOKEN, host=host, fabric=fabric)
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=get_free_port(), log_level="warning",
                                           lifespan="off"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    driver = None
    try:
        wait_for(lambda: server.started or not thread.is_alive(), 30, "uvicorn to start")
        base = f"http://127.0.0.1:{server.config.port}"
        driver = _driver(1200, 800)
        open_page(driver, base + path)
        yield app, driver, base
    finally:
        if driver is not None:
            driver.quit()
        roles.stop.set()
        server.should_exit = True
        thread.join(timeout=10)


def open_page(driver, url: str) -> None:
    """Load ``url`` and wait until the page has polled the status twice."""
    from selenium.webdriver.support.ui import WebDriverWait

    driver.get(url)
    WebDriverWait(driver, 60, poll_frequency=0.2).until(lambda d: d.execute_script(POLLED))


def click(driver, instance: str, action: str) -> str:
    """Press one of ``instance``'s buttons; the answer the page shows under them."""
    panel = driver.find_element("css selector", f".operator[data-instance='{instance}']")
    panel.find_element("css selector", f"button[data-action='{action}']").click()
    return wait_for(lambda: (t := panel.find_element("css selector", ".answer").text)
                    and not t.endswith("sending…") and t != "no command sent yet" and t, 20, f"the answer to {action}")


def test_a_robot_actor_gets_buttons_that_reach_it_over_zenoh(router):
    run = Roles(running("actor", "actor-0", episodes=3, env_steps=9),
                running("robot", "robot-0", {"arm": "franky-sim"}, episodes=2, env_steps=6, paused=0.0))
    dash, robot = open_session(router), open_session(router)
    heard = []
    channel = OperatorChannel(on_stop=lambda: heard.append("stop"), on_resume=lambda: heard.append("resume"))
    listener = FabricOperator(robot, RUN_ID, "robot-0", channel)
    try:
        with page(run, path="/") as (app, driver, base):  # on loopback the page reads without the token...
            assert click(driver, "robot-0", "stop").startswith(  # ...but sends no command without it
                "stop: error, token required: open the dashboard's URL with its token")
            open_page(driver, f"{base}/?token={TOKEN}")  # the URL the dashboard logs
            panel = driver.find_element("css selector", "#operator-panel")
            assert panel.is_displayed()
            buttons = panel.find_elements("css selector", ".operator[data-instance='robot-0'] button")
            assert [b.text for b in buttons] == ["Success", "Fail", "Reset done", "Resume", "STOP"]
            assert "franky-sim" in panel.text
            assert len(driver.find_elements("css selector", ".operator")) == 1  # the simulated actor has none

            assert click(driver, "robot-0", "stop").startswith("stop: error, the operator channel is not connected")
            app.state.operator = OperatorPublisher(dash, RUN_ID)  # as the dashboard role does once its session is up

            assert click(driver, "robot-0", "reset_done").startswith("reset_done: ok (command #1")
            assert channel.wait_for({OperatorAction.RESET_DONE}, NEVER, timeout_s=10) is OperatorAction.RESET_DONE
            open_page(driver, f"{base}/")  # reloaded without it in the URL: the tab kept the token
            assert click(driver, "robot-0", "stop").startswith("stop: ok")
            wait_for(lambda: channel.paused, 10, "the robot actor to pause")
            assert click(driver, "robot-0", "resume").startswith("resume: ok")
            wait_for(lambda: not channel.paused, 10, "the robot actor to resume")
            assert click(driver, "robot-0", "success").startswith("success: ok")
            assert channel.wait_for({OperatorAction.SUCCESS}, NEVER, timeout_s=10) is OperatorAction.SUCCESS

            from selenium.webdriver.common.action_chains import ActionChains
            from selenium.webdriver.common.keys import Keys

            ActionChains(driver).send_keys(Keys.ESCAPE).perform()  # the STOP key, with one robot on the page
            wait_for(lambda: channel.paused, 10, "Escape to stop the robot actor")
            assert heard == ["stop", "resume", "stop"]
    finally:
        listener.close()
        robot.close()
        dash.close()


def test_a_run_without_a_robot_shows_no_operator_panel():
    with page(Roles(running("actor", "actor-0", episodes=3, env_steps=9))) as (_, driver, _):
        assert driver.find_elements("css selector", "#actor-rows tr[data-instance='actor-0']")
        assert not driver.find_element("css selector", "#operator-panel").is_displayed()
        assert not driver.find_elements("css selector", ".operator")
        assert not driver.find_element("css selector", "#fabric").is_displayed()  # plain loopback: no banner


def test_bound_beyond_loopback_the_page_opens_with_its_token_and_says_the_fabric_is_insecure():
    """Bound to 0.0.0.0 (reached at 127.0.0.1) every route needs the token: the page's fetches send it, what
    the browser loads by itself (scripts, styles) rides on the cookie the tokened page set."""
    run = Roles(running("robot", "robot-0", {"arm": "franky-sim"}, episodes=2, env_steps=6, paused=0.0))
    with page(run, host="0.0.0.0", fabric="insecure") as (app, driver, base):
        banner = driver.find_element("css selector", "#fabric")
        assert banner.is_displayed() and banner.text == ("fabric: INSECURE (plain TCP beyond loopback, every host "
                                                         "that reaches the router is trusted)")
        assert driver.execute_script("return getComputedStyle(document.querySelector('#fabric')).backgroundColor") \
            == "rgb(185, 28, 28)"  # style.css loaded: a red banner
        assert driver.find_element("css selector", "#offline").get_attribute("hidden") is not None
        severe = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        assert not severe, severe  # every script, style and answer loaded
        assert click(driver, "robot-0", "stop").startswith("stop: error, the operator channel is not connected")

        open_page(driver, f"{base}/")  # a reload without the token in its URL keeps working
        assert driver.find_element("css selector", "#fabric").is_displayed()

        driver.delete_all_cookies()  # a browser that never had the token
        driver.execute_script("sessionStorage.clear()")
        driver.get(f"{base}/")
        assert "token required" in driver.find_element("tag name", "body").text
        assert app.state.access.refused >= 1
