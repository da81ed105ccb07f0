"""Package discovery for normbox-lab (all metadata lives in pyproject.toml).

The design card fixes the top-level folders drivers/, sim/ and protocols/. Their names are
generic, so they are installed *inside* the application's namespace as normbox_lab.drivers,
normbox_lab.sim and normbox_lab.protocols; every package below them is found, not listed.
"""

from setuptools import find_packages, setup

MAPPED_FOLDERS = {"drivers": "normbox_lab.drivers", "sim": "normbox_lab.sim",
                  "protocols": "normbox_lab.protocols"}

packages = find_packages(include=["normbox_lab", "normbox_lab.*"])
package_dir = {"normbox_lab": "normbox_lab"}
for folder, name in MAPPED_FOLDERS.items():
    package_dir[name] = folder
    packages += [name] + [f"{name}.{sub}" for sub in find_packages(folder)]

#: data files shipped inside the packages (read at run time, in editable and normal installs;
#: listed here only: `include_package_data` would also take any stray file in a package folder)
PACKAGE_DATA = {"normbox_lab.sim": ["data/*.npz"]}

setup(packages=packages, package_dir=package_dir, package_data=PACKAGE_DATA,
      include_package_data=False)
