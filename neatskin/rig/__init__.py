"""The campaign engine: protocols, the plan, the runner, and the assembly of a real or a dry rig.

protocol (protocol files: CampaignProtocol), plan (Plan, build_plan), runner (run, resume, finish), pressing
(the press loop), assembly (Rig and the device protocols it is typed with; the real rig), dryrig (the dry
rig: simulated printer and skin), folder (the campaign folder), physlimit (a dry run's physical limit),
recorder (the real rig's threaded recorder), pressrow (one press's values and FSR label), control (pause,
stop), cli (`neatskin campaign ...`). The only package that composes the others.
"""
