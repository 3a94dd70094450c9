from setuptools import find_packages, setup

package_name = "katana_sim"

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
    description="PyBullet simulation of the Katana and sim_node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim_node = katana_sim.sim_node:main",
        ],
    },
)
