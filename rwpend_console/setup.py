from setuptools import setup

package_name = 'rwpend_console'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    package_data={package_name: ['static/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    description='The lab console (a web page: live plots, gains, e-stop) and the Foxglove bridge.',
    license='Apache-2.0',
)
