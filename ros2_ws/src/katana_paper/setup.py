from setuptools import find_packages, setup

package_name = "katana_paper"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Katana curiosity maintainers",
    maintainer_email="katana-curiosity@example.org",
    description="The research harness: the paper's experiments, figures and robot reproduction.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "katana-curiosity = katana_paper.curiosity_cli:main",
            "katana-robot = katana_paper.robot_cli:main",
        ],
    },
)
