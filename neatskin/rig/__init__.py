"""The campaign engine: protocols, the plan, the runner, and the assembly of a real or a dry rig.

protocol (protocol files), runner (plan, run, resume), assembly (build a dry or real rig from
devices behind the same protocols), recorder (the real rig's threaded recorder), pressrow (one
press's values and FSR label), cli (`neatskin campaign ...`). The only package that composes
the others.
"""
