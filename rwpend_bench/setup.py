from setuptools import setup

package_name = 'rwpend_bench'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    description='The harness: tools users run to measure the stack (bench, soak, the test network); '
                'product packages import none of it.',
    license='Apache-2.0',
)
