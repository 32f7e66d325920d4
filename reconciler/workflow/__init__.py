"""Use cases written once for every caller — the CLI, the agent, the Bluetooth service and
the `libpanda-app-manager` shim: each takes its ports and a report callback, and returns
what happened. Every rule — the lock, the gates, holds, defaults — is here, never in a
caller; the rules that are pure (holds, the planner's modes) are in core/planning.

plan: planning.plan_file / plan · apply: applying.apply_file / apply · a saved plan:
applying.apply_plan_file / apply_saved · start|stop|restart: operate.operate_installed ·
rollback: operate.roll_back · gates in force and now: gates · history: history · logs:
logs · sync and agent: agent (one_pass, Agent), sync · bundle: packing, bundle · pin: pin ·
fleet: fleet · import-lpam: importing · the phone's and the shim's edits: editing ·
the app table: inventory · local overrides: override · what a fleet car follows: followed ·
validate: validation · status: reconciler/report/status.py · defaults: defaults.
"""
