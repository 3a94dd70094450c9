from setuptools import find_packages, setup

package_name = "katana_curiosity"

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
    description="The curiosity algorithm, its worlds, the robot loop and its two nodes.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "curiosity_node = katana_curiosity.curiosity_node:main",
            "skill_node = katana_curiosity.skill_node:main",
        ],
    },
)
