from setuptools import setup

package_name = 'rwpend_lab'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    package_data={package_name: ['templates/*.py']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    description="The lab: the book's 20 experiments, one command each, with a report.",
    license='Apache-2.0',
)
