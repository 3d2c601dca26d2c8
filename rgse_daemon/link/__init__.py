"""The link to the KR C4's variable server (C3 Bridge or KUKAVARPROXY): the frame codec (:mod:`.frames`), KRL value
strings (:mod:`.krlvalue`), one connection with one request in flight (:mod:`.connection`), a pool of them with
protocol detection (:mod:`.pool`) and the link's errors (:mod:`.errors`). Bytes and KRL values only, no numpy
(pyproject.toml contract)."""
