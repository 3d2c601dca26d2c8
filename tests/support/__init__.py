"""What the tests share: polling, a private broker, campaign and trace writers, simulators as fixtures.

Tests import helpers only from here (and fixtures from the conftest files); no test module imports another.
"""
