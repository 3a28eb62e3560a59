"""The live Foxglove connection: foxglove-sdk's WebSocket server fed by the ground
station's port tap, read by a real WebSocket client (headless Chromium's) speaking the
Foxglove protocol: advertise, subscribe, a message whose CDR bytes rclpy decodes."""

from __future__ import annotations

import struct
import threading

import pytest

from bridge.ros.rosport.msgs import Odometry
from tests.browser import chromium

pytestmark = pytest.mark.browser

# Subscribe to one topic, resolve with the first message's payload (opcode 1: message
# data, subscription id u32, log time u64, then the message).
CLIENT_JS = """
([url, topic]) => new Promise((resolve, reject) => {
  const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
  ws.binaryType = "arraybuffer";
  const timer = setTimeout(() => reject(new Error("no message in 20 s")), 20000);
  ws.onmessage = (e) => {
    if (typeof e.data === "string") {
      const m = JSON.parse(e.data);
      if (m.op === "advertise") {
        const ch = m.channels.find((c) => c.topic === topic);
        const subscriptions = [{id: 7, channelId: ch ? ch.id : -1}];
        if (ch) ws.send(JSON.stringify({op: "subscribe", subscriptions}));
      }
      return;
    }
    const bytes = new Uint8Array(e.data);
    if (bytes[0] !== 1) return;
    clearTimeout(timer);
    ws.close();
    resolve({schemaEncoding: "ros2msg", bytes: Array.from(bytes)});
  };
  ws.onerror = () => reject(new Error("websocket error"));
})
"""


# foxglove-sdk keeps one tokio runtime per process (its eventfd, epoll and wake-up
# sockets) from the first server on: a process-wide resource, not a leak of this test.
@pytest.mark.allow_leaks
def test_the_ground_stations_messages_reach_a_foxglove_client() -> None:
    pytest.importorskip("foxglove")
    from rclpy.serialization import deserialize_message

    from planner.record.foxlive import FoxgloveLive

    with pytest.raises(ValueError, match="no token"):
        FoxgloveLive(host="0.0.0.0")
    msg = Odometry()
    msg.pose.pose.position.x = 2.5
    msg.pose.pose.orientation.w = 1.0
    stop = threading.Event()
    with FoxgloveLive(port=0) as live:
        live.tap("received", "/ground/odom_ground", msg)  # the channel is advertised

        def feed() -> None:
            while not stop.wait(0.05):
                live.tap("received", "/ground/odom_ground", msg)

        feeder = threading.Thread(target=feed)
        feeder.start()
        try:
            with chromium() as browser:
                page = browser.new_page()
                got = page.evaluate(CLIENT_JS, [live.url, "/ground/odom_ground"])
                page.close()
        finally:
            stop.set()
            feeder.join(5)
    data = bytes(got["bytes"])
    opcode, subscription, _log_time = struct.unpack_from("<BIQ", data)
    assert (opcode, subscription) == (1, 7)
    decoded = deserialize_message(data[13:], Odometry)
    assert decoded.pose.pose.position.x == 2.5
