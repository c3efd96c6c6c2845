"""Synthetic run of the stack, written as a bag (for tests and demos; no rclpy).

CDR bytes are made with rosbags' serializer from our .msg definitions, so the bags are
independent of our own decoder. The run: pendulum swings up in ``t_up`` s (energy pumping),
catch, then balances with a wheel limit cycle of period ``lc_period`` and amplitude ``lc_amp``.
"""
from __future__ import annotations

import math

import numpy as np

from rwpend_bag import msgdefs
from rwpend_control.status_codes import FAULT_NONE, SWITCH_CATCH, SWITCH_SET_MODE

TYPES = {'/rwpend/encoders': 'rwpend_msgs/msg/EncoderCounts',
         '/rwpend/command': 'rwpend_msgs/msg/MotorCommand',
         '/rwpend/state': 'rwpend_msgs/msg/StateEstimate',
         '/rwpend/sim/true_state': 'rwpend_msgs/msg/PlantState',
         '/rwpend/controller/status': 'rwpend_msgs/msg/ControllerStatus'}


def typestore():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    store = get_typestore(Stores.EMPTY)
    for t in TYPES.values():
        store.register(get_types_from_msg(msgdefs.joined_definition(t), t))
    return store


def make_run(duration=10.0, rate=1000.0, t_up=3.0, lc_period=2.0, lc_amp=0.5, latency=4e-4,
             drop_command=(), t0_ns=1_700_000_000_000_000_000):
    """List of (topic, type, log_time_ns, cdr bytes) in time order, and the truth used."""
    store = typestore()
    ser = store.serialize_cdr
    M = {t: store.types[t] for t in TYPES.values()}
    Time = store.types['builtin_interfaces/msg/Time']
    Header = store.types['std_msgs/msg/Header']
    n = int(duration * rate)
    h = 1.0 / rate
    out = []
    law = 'swingup'
    switches = 0
    last_switch = 0
    for k in range(n):
        t = k * h
        if t < t_up:
            theta = math.pi * (t / t_up) ** 2
            theta_dot = 2 * math.pi * t / t_up ** 2
        else:
            theta = math.pi + 0.01 * math.sin(2 * math.pi * (t - t_up) / lc_period)
            theta_dot = 0.01 * 2 * math.pi / lc_period * math.cos(2 * math.pi * (t - t_up) / lc_period)
        wheel = (lc_amp * math.sin(2 * math.pi * (t - t_up) / lc_period) + 3.0
                 if t >= t_up else 3.0 * t / t_up)
        wheel_rate = (lc_amp * 2 * math.pi / lc_period * math.cos(2 * math.pi * (t - t_up) / lc_period)
                      if t >= t_up else 3.0 / t_up)
        u = 10.0 if t < t_up * 0.5 else (-10.0 if t < t_up else 2.0 * math.sin(2 * math.pi * t))
        ns = t0_ns + int(round(t * 1e9))
        stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        hdr = Header(stamp=stamp, frame_id='rig')
        enc = M['rwpend_msgs/msg/EncoderCounts'](header=hdr, seq=k,
                                                  pendulum_counts=int(theta / (2 * math.pi) * 4000),
                                                  motor_counts=int((wheel - theta) / (2 * math.pi) * 4000))
        out.append(('/rwpend/encoders', ns, bytes(ser(enc, 'rwpend_msgs/msg/EncoderCounts'))))
        ps = M['rwpend_msgs/msg/PlantState'](header=hdr, seq=k, command_seq=k - 1, theta=theta, theta_dot=theta_dot,
                                             wheel_angle=wheel, wheel_rate=wheel_rate,
                                             u_commanded=u, u_applied=u, friction=0.0,
                                             disturbance=0.0, stuck=False, command_timeout=False)
        out.append(('/rwpend/sim/true_state', ns, bytes(ser(ps, 'rwpend_msgs/msg/PlantState'))))
        energy = 1 - math.cos(theta) + 0.5 * (theta_dot / 6.0) ** 2
        # one re-synchronisation of the estimator half way, after 40 missing samples
        st = M['rwpend_msgs/msg/StateEstimate'](header=hdr, seq=k, theta=theta, theta_dot=theta_dot,
                                                wheel_angle=wheel, wheel_rate=wheel_rate,
                                                friction=0.0, energy=energy, resyncs=int(k >= n // 2),
                                                missed=40 if k == n // 2 else 0, estimator='observer3')
        out.append(('/rwpend/state', ns + 100_000, bytes(ser(st, 'rwpend_msgs/msg/StateEstimate'))))
        if k not in drop_command:
            cns = ns + int(latency * 1e9)
            chdr = Header(stamp=Time(sec=cns // 1_000_000_000, nanosec=cns % 1_000_000_000),
                          frame_id='rig')
            cmd = M['rwpend_msgs/msg/MotorCommand'](header=chdr, seq=k, u=u, controller_id=0, release=False)
            out.append(('/rwpend/command', cns, bytes(ser(cmd, 'rwpend_msgs/msg/MotorCommand'))))
        new_law = 'swingup' if t < t_up else ('catch' if t < t_up + 0.5 else 'balance')
        if new_law != law:
            law, switches, last_switch = new_law, switches + 1, ns
        if k % 10 == 0:
            cs = M['rwpend_msgs/msg/ControllerStatus'](
                header=hdr, seq=k, mode='auto', law=law, u=u, u_unsaturated=u * 1.2,
                friction_compensation=0.0, saturated=abs(u) >= 10,
                last_switch=Time(sec=last_switch // 1_000_000_000, nanosec=last_switch % 1_000_000_000),
                switch_count=switches, switch_code=SWITCH_SET_MODE if law == 'swingup' else SWITCH_CATCH,
                reason='', fault_code=FAULT_NONE, fault='')
            out.append(('/rwpend/controller/status', ns + 200_000,
                        bytes(ser(cs, 'rwpend_msgs/msg/ControllerStatus'))))
    out.sort(key=lambda x: x[1])
    return out


def write_ours(path, records, qos=None):
    from rwpend_bag.writer import BagWriter, default_qos
    w = BagWriter(path)
    for topic, typ in TYPES.items():
        w.add_topic(topic, typ, [qos or default_qos(depth=10, history='keep_last')])
    for topic, ns, data in records:
        w.write(topic, data, ns)
    w.close()
    return w


def write_rosbags(path, records):
    from rosbags.rosbag2 import StoragePlugin, Writer
    store = typestore()
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {topic: w.add_connection(topic, typ, typestore=store) for topic, typ in TYPES.items()}
        for topic, ns, data in records:
            w.write(conns[topic], ns, data)
