"""The harness: tools users run to measure the stack (./rwpend bench, ./rwpend soak, the test
network of network namespaces); product packages import none of it."""
