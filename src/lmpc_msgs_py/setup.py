from setuptools import setup

package_name = "lmpc_msgs_py"

setup(
    name=package_name,
    version="0.1.0",
    packages=[package_name],
    package_data={package_name: ["config/*.yaml", "config/*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config",
         [package_name + "/config/decision_space.yaml",
          package_name + "/config/fastdds_local_discovery.xml"]),
    ],
    install_requires=["setuptools", "pydantic>=2.7,<3", "pyyaml>=6,<7"],
    python_requires=">=3.10",
    zip_safe=True,
    maintainer="LanguageMPC ROS 2 maintainers",
    description="LanguageMPC message schemas, JSON codec, topic names and QoS profiles.",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": []},
)
