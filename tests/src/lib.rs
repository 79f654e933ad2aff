//! cabc-tests: end-to-end tests that start the real binaries on loopback (see tests/tests/).
