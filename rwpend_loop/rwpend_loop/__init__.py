"""The loop of the rig: one sample as plain calls in one thread (rwpend_loop.loop), its pacer
(rwpend_loop.pacer) and the process that hosts the nodes around it (rwpend_loop.host)."""
