"""The test suite: unit tests mirroring the packages (``unit/<package>``), end-to-end tests
(``e2e``) and the documented testing helpers (``helpers``)."""
