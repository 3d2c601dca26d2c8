"""Simulated outside world for tests and the demo: KR C4 controller, Modbus I/O module, crane scale."""
