"""Drive zmotor's motor screen in headless Chromium (Debian's chromium and chromedriver, through
Selenium): open the index, open the axis, click tweak-forward and see the motor move on the page
and in the plot, type a target beyond the soft limit and see the node's refusal; keep a
screenshot; close the page's socket and see it reconnect and drive the axis again. A line `ok <check>` is printed for each check that passed.

Usage: python3 web_screen.py URL AXIS SCREENSHOT [jog | hold]
The axis's tweak step (TWV) is 1. With `jog`: hold JOGF down until the page shows the motion,
then kill the browser (SIGKILL) with the button still held, and print when (`killed <unix time>`).
With `hold`: hold JOGF down and wait, until SIGTERM closes the browser (a link cut meanwhile).
"""
import sys

from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.ui import WebDriverWait

import os

url, axis, screenshot = sys.argv[1:4]
mode = (sys.argv[4:] or ["screen"])[0]


def ok(check):
    print("ok", check, flush=True)


def d_text(driver, element):
    return driver.find_element(By.ID, element).text


options = Options()
options.binary_location = os.environ.get("ZMOTOR_CHROMIUM", "/usr/bin/chromium")
for argument in ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,1300"]:
    options.add_argument(argument)
service = Service(os.environ.get("ZMOTOR_CHROMEDRIVER", "/usr/bin/chromedriver"))
driver = webdriver.Chrome(service=service, options=options)
try:
    wait = WebDriverWait(driver, 20)
    if mode in ("jog", "hold"):
        from selenium.webdriver.common.action_chains import ActionChains

        driver.get(url + "axis/" + axis)
        wait.until(lambda d: d.find_element(By.ID, "live").text == "live")
        ActionChains(driver).click_and_hold(driver.find_element(By.ID, "jogf")).perform()
        wait.until(lambda d: d.find_element(By.ID, "motion").text == "moving")
        ok("jogging, the button held")
        if mode == "hold":
            import signal
            import time

            signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
            time.sleep(600)
        # Kill the browser this script started (chromedriver's children), the button still
        # held: nothing of the page runs to release it.
        import os
        import signal
        import time

        driver_pid = driver.service.process.pid
        with open(f"/proc/{driver_pid}/task/{driver_pid}/children") as children:
            browsers = [int(pid) for pid in children.read().split()]
        killed_at = time.time()
        for pid in browsers:
            os.kill(pid, signal.SIGKILL)
        print(f"killed {killed_at:.6f}", flush=True)
        sys.exit(0)
    driver.get(url)
    wait.until(lambda d: d.find_elements(By.LINK_TEXT, axis))[0].click()
    ok("the index lists the axis")

    def rbv():
        return driver.find_element(By.CSS_SELECTOR, 'td[data-cell="RBV"] span').text

    wait.until(lambda d: rbv() != "")
    before = float(rbv())
    plotted = driver.execute_script("return window.zmotorPlot.RBV.length")
    driver.find_element(By.ID, "twf").click()
    wait.until(lambda d: abs(float(rbv()) - (before + 1.0)) < 1e-9)
    ok("tweak forward moves the motor and the page shows its readback")
    positions = driver.execute_script("return window.zmotorPlot.RBV.map(p => p[1])")
    assert len(positions) > plotted + 1, positions
    assert min(positions) <= before and max(positions) >= before + 1.0 - 1e-9, positions
    assert any(before < p < before + 1.0 for p in positions), positions
    ok("the plot follows the motion")

    target = driver.find_element(By.CSS_SELECTOR, 'td[data-cell="VAL"] input')
    # Focused first: a field being typed in is not overwritten by the axis's posts.
    target.click()
    target.send_keys(Keys.CONTROL, "a")
    target.send_keys("500", Keys.ENTER)
    try:
        wait.until(lambda d: "limit" in d.find_element(By.ID, "error").text)
    except Exception:
        driver.save_screenshot(screenshot)
        raise AssertionError("no refusal shown: error %r, VAL %r" % (
            driver.find_element(By.ID, "error").text, target.get_attribute("value")))
    assert abs(float(rbv()) - (before + 1.0)) < 1e-9
    ok("a target beyond the soft limit is refused with the node's words, and nothing moves")
    driver.save_screenshot(screenshot)
    ok("screenshot")

    # A socket that closes is opened again: the page is live and drives the axis once more.
    driver.execute_script("window.zmotorLost = window.zmotorSocket(); window.zmotorLost.close()")
    wait.until(lambda d: d_text(d, "live").startswith("disconnected"))
    wait.until(lambda d: d.execute_script("return window.zmotorSocket() !== window.zmotorLost") and d_text(d, "live") == "live")
    driver.find_element(By.ID, "twf").click()
    wait.until(lambda d: abs(float(rbv()) - (before + 2.0)) < 1e-9)
    ok("a closed socket reconnects and the page drives the axis again")

    # The screen of an axis nobody serves says so, and leads back to the index.
    driver.get(url + "axis/nosuch")
    wait.until(lambda d: d.find_element(By.ID, "unserved").is_displayed())
    assert d_text(driver, "live") == "not served", d_text(driver, "live")
    driver.find_element(By.CSS_SELECTOR, "#unserved a").click()
    wait.until(lambda d: d.find_elements(By.LINK_TEXT, axis))
    ok("an axis nobody serves is said to be not served, with a link to the index")
finally:
    driver.quit()
