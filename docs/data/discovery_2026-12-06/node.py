import sys, time, os, json
t_start = float(sys.argv[2])
import random; time.sleep(random.uniform(0, 0.8))
import rclpy
from rclpy.node import Node
from std_msgs.msg import String
name = sys.argv[1]
rclpy.init()
n = Node("n_" + name)
pubs = {t: n.create_publisher(String, "/t_" + name + "_" + t, 10) for t in "abc" if t != name}
subs = [n.create_subscription(String, "/t_" + o + "_" + name, lambda m: None, 10) for o in "abc" if o != name]
t_node = time.time()
deadline = time.time() + 8
while time.time() < deadline:
    if all(p.get_subscription_count() >= 1 for p in pubs.values()):
        break
    rclpy.spin_once(n, timeout_sec=0.01)
print(json.dumps({"name": name, "node_up": t_node - t_start, "matched": time.time() - t_start, "ok": all(p.get_subscription_count() >= 1 for p in pubs.values())}))
time.sleep(1.0)
