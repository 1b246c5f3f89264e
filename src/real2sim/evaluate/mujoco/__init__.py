"""The evaluation's tasks rebuilt in MuJoCo: the same scenes around a representation's model.xml, and
its candidate simulations under the same equation-error protocol, against the same Drake reference."""
