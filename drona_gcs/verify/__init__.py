"""The systematic tester: the real stack over an in-memory network, explored under approximate synchrony."""
