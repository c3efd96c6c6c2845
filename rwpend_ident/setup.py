from setuptools import setup

package_name = 'rwpend_ident'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    package_data={package_name: ['config/*.yaml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    description='Identification of a real rig: from a new rig to its rig YAML.',
    license='Apache-2.0',
)
