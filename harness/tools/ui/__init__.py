"""The campaign web page (`stella ui`)."""
