"""Test support: the lab network of test hosts in network namespaces (:mod:`support.netlab`),
its delay line (:mod:`support.delayline`) and the stack split across its hosts
(:mod:`support.netrun`). Not part of the product: only tests import it."""
