from glob import glob

from setuptools import find_packages, setup

package_name = 'rbc_registration'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        # bag reading without ROS needs the interface definitions (io/bag/typestore.py)
        ('share/' + package_name + '/msg', glob('msg_docs/rbc_registration_interfaces/msg/*.msg')),
    ],
    python_requires='>=3.10',
    # Lowest versions CI runs the pure suite with (Ubuntu 24.04's apt numpy / scipy / matplotlib /
    # yaml, constraints-ubuntu2404.txt); the pins of constraints.txt are the highest tested.
    install_requires=['numpy>=1.26', 'scipy>=1.11', 'matplotlib>=3.6', 'rosbags>=0.11.0',
                      'pyyaml>=6.0.1'],
    extras_require={'test': ['pytest', 'hypothesis']},
    zip_safe=True,
    maintainer='rbc_registration maintainers',
    maintainer_email='maintainer@example.com',
    description=(
        'Rigid-body registration from fiducials affected by bias and noise, improved by '
        'restoring the rigid-body condition (ROS 2 node, CLI and library).'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'rbc-registration = rbc_registration.cli:main',
            'registration_node = rbc_registration.ros.node:main',
        ],
    },
)
