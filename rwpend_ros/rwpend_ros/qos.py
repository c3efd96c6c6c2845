"""QoS profiles of the stack's topics (one place for every node, the recorder and the tools)."""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Control path (encoders, command, state, joint_states): reliable, keep-last 1000 on both
#: sides. Reliable delivery lost no samples across processes in our measurements
#: (ENVIRONMENT.md) and lets a reliable recorder match every publisher; the depth of 1000 (1 s at
#: 1 kHz) is what survives a stalled reader: with depth 10, a recorder stalled 40-60 ms by a
#: loaded CPU lost 150 of 10000 samples and an estimator fed by the player 60 (measured). A
#: reader that falls behind works through the backlog in order; the plant ignores commands
#: answering an older sample than the newest it holds.
QOS_CONTROL = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=1000, durability=DurabilityPolicy.VOLATILE)
#: Publishers of the control path: reliable, keep-last 100. The depth that protects a stalled
#: reader is its own (subscriptions keep 1000: a sample, once delivered, waits in
#: the reader's history); the writer's history only serves repairs. With 1000 here, every
#: publisher of a 1 kHz topic stalled for 1.5-2.5 ms about once a second (once per history's
#: worth of samples), which made ~1 % of the commands late; with 100 the stalls are gone
#: (PERFORMANCE.md).
QOS_CONTROL_PUB = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                             depth=100, durability=DurabilityPolicy.VOLATILE)
#: The controller's input (state): reliable, keep-last 5. A controller that fell behind acts on
#: the newest state and drops the older ones, instead of working through a backlog of stale
#: states (in real time an old state is worse than none; the plant's timeout covers the gap).
#: The estimator keeps QOS_CONTROL: every sample feeds its observers.
QOS_CONTROL_LATEST = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                                depth=5, durability=DurabilityPolicy.VOLATILE)
#: Status and diagnostics.
QOS_STATUS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        depth=100, durability=DurabilityPolicy.VOLATILE)
#: The recorder's progress in lockstep (``--progress``: the newest /clock it took, every
#: RECORDER_PROGRESS_EVERY of them) and the simulator's subscription to it.
QOS_PROGRESS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                          depth=10, durability=DurabilityPolicy.VOLATILE)

RECORDER_PROGRESS_EVERY = 10
#: bounds of the simulator's lockstep_recorder_window (samples): above twice the recorder's
#: reporting step (else the run could wait for a report that only comes later), below the
#: publishers' depth (QOS_CONTROL_PUB, 100) less that step (a reader that lags more loses samples)
RECORDER_WINDOW_MIN = 2 * RECORDER_PROGRESS_EVERY

RECORDER_WINDOW_MAX = 80
#: Latched state (e-stop): a late joiner gets the last value.
QOS_LATCHED = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: A subscription that matches every publisher, whatever its QoS: best effort and volatile
#: (DDS matches a reader whose offers are no stronger than the writer's). With a QOS_LATCHED
#: subscription beside it, the e-stop reaches the plant from any publisher a user types --
#: ``ros2 topic pub`` with its defaults (volatile) included -- and a latched one is replayed.
QOS_ANY_PUBLISHER = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST,
                               depth=10, durability=DurabilityPolicy.VOLATILE)
