"""The simulated KUKA KR C4 controller (C3 Bridge / KUKAVARPROXY server, KRL execution, physics, KUKA Trace)."""
