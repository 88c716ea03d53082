from glob import glob

from setuptools import find_packages, setup

package_name = "lmpc_mpc"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={package_name: ["config/*.yaml", "data/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob(package_name + "/config/*.yaml")),
    ],
    install_requires=["setuptools", "lmpc_msgs_py", "numpy>=1.26,<3", "casadi>=3.6.5,<4",
                      "pyyaml>=6,<7"],
    python_requires=">=3.10",
    zip_safe=False,
    maintainer="LanguageMPC ROS 2 maintainers",
    description="LanguageMPC MPC: Bezier reference candidates, prediction, CasADi MPC, "
                "weight pool.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "mpc_controller = lmpc_mpc.mpc_node:main",
        ],
    },
)
