"""``python -m sbagents.federated.personalize``: fine-tune a finished SmartHome run's policy in one home.

The home is a client home of the run's federation (``--home I``, with the run's draw of users) or any user
(``--preferred-temp T --preferred-light L``); prints the home's comfort and energy use before and after, and writes
the personal model as a run dir of its own.
"""

from __future__ import annotations

from sbagents.cli_common import ArgumentParser, add_run_arguments, run
from sbagents.errors import UsageError


def build_parser() -> ArgumentParser:
    p = ArgumentParser(prog="python -m sbagents.federated.personalize",
                       description="Fine-tune a SmartHome policy in one home; comfort before and after.")
    add_run_arguments(p, load_best=False, trust=False)
    p.add_argument("--home", type=int, default=None, help="client home I of the run's federation")
    p.add_argument("--preferred-temp", type=float, default=None, help="the home's user: preferred temperature (C)")
    p.add_argument("--preferred-light", type=float, default=None, help="the home's user: preferred light (lux)")
    p.add_argument("-n", "--n-timesteps", type=int, default=2000, help="fine-tuning budget in env steps (2000)")
    p.add_argument("--eval-episodes", type=int, default=20, help="episodes before and after (20)")
    p.add_argument("--seed", type=int, default=0, help="seed of the fine-tuning and of the evaluation episodes")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from sbagents.cli_common import run_ref
    from sbagents.core.run_dir import config_path, find_run_dir
    from sbagents.core.zoo_config import load_yaml
    from sbagents.federated.console import personal_line
    from sbagents.federated.homes import Home, client_homes
    from sbagents.federated.personal import personalize
    from sbagents.federated.settings import FederatedSettings

    own = args.preferred_temp is not None or args.preferred_light is not None
    if (args.home is not None) == own or (own and (args.preferred_temp is None or args.preferred_light is None)):
        raise UsageError("give --home I, or --preferred-temp T with --preferred-light L")
    ref = run_ref(args)
    algo, env_id = str(ref.algo), ref.env_ref().env_id
    run_dir = find_run_dir(ref.log_folder, algo, env_id, ref.exp_id)
    if own:
        home = Home(0, "own", args.preferred_temp, args.preferred_light)
    else:
        args_file = config_path(run_dir, env_id).with_name("args.yml")
        federated = (load_yaml(args_file) or {}).get("federated") if args_file.exists() else None
        if not federated:
            raise UsageError(f"{run_dir} is not a federated run: give the user with --preferred-temp/--preferred-light")
        settings = FederatedSettings.from_run_config(federated)
        if not 0 <= args.home < settings.homes:
            raise UsageError(f"--home {args.home}: the run had homes 0..{settings.homes - 1}")
        home = client_homes(settings.homes, settings.seed)[args.home]
    import torch

    torch.set_num_threads(1)
    result = personalize(run_dir, algo, env_id, home, args.n_timesteps, args.eval_episodes, args.seed,
                         ref.log_folder)
    print(f"{home.describe()}")
    print(personal_line(result))
    return 0


if __name__ == "__main__":
    run("python -m sbagents.federated.personalize", main)
