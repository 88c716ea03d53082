from glob import glob

from setuptools import setup

package_name = "lmpc_bridge"

setup(
    name=package_name,
    version="0.1.0",
    packages=[package_name, package_name + ".scenarios", package_name + ".evaluation",
              package_name + ".render"],
    package_data={package_name: ["config/*.yaml", "data/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob(package_name + "/config/*.yaml")),
    ],
    install_requires=[
        "setuptools", "lmpc_msgs_py", "numpy>=1.26,<3", "libsumo>=1.20,<2",
        "eclipse-sumo>=1.20,<2", "pyyaml>=6,<7",
    ],
    # lmpc_bridge.render (the pictures) is the only user of matplotlib / pillow
    # lmpc_bridge.gym_env (the learned planners' environment, docs/RL.md) needs gymnasium
    extras_require={"render": ["matplotlib>=3.8,<4", "pillow>=10"],
                    "rl": ["gymnasium>=1.0,<2"]},
    python_requires=">=3.10",
    zip_safe=False,
    maintainer="LanguageMPC ROS 2 maintainers",
    description="LanguageMPC SUMO bridge: scenarios, ego dynamics, observations, metrics.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "sumo_bridge = lmpc_bridge.bridge_node:main",
        ],
    },
)
