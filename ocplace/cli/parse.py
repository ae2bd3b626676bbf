"""`ocplace parse "..."` and `ocplace parse-eval`."""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

from ocplace.cli.options import MAX_DURATION_S, MAX_SEED, count, number
from ocplace.models.parsing.config import CROSS_CHECK_POLICIES, PARSER_NAMES


def register(subparsers) -> None:
    parse = subparsers.add_parser("parse", help="parse an instruction into <reference, relation> tuples")
    parse.add_argument("instruction", help='e.g. "put it to the left of the red bowl"')
    _add_parser_options(parse)
    parse.add_argument("--json", action="store_true", help="print the tuples as JSON")
    parse.set_defaults(func=_parse)

    evaluate = subparsers.add_parser(
        "parse-eval", help="parser accuracy and latency on seen, unseen and free-form instructions"
    )
    _add_parser_options(evaluate)
    evaluate.add_argument(
        "--num", type=count(1, 1_000_000), default=2000, help="generated instructions per template style (default 2000)"
    )
    evaluate.add_argument(
        "--seed", type=count(0, MAX_SEED), default=0, help="seed of the generated instructions (default 0)"
    )
    evaluate.add_argument(
        "--names", help="text file with one object name per line (default: the built-in list of ~50 tabletop objects)"
    )
    evaluate.add_argument("--freeform", help="free-form JSONL file (default: the shipped set)")
    evaluate.add_argument(
        "--show-failures", type=count(0, 10_000), default=5, metavar="K", help="print up to K failures per set"
    )
    evaluate.set_defaults(func=_parse_eval)


def _add_parser_options(command: argparse.ArgumentParser) -> None:
    command.add_argument("--parser", choices=PARSER_NAMES, default="offline", help="which parser (default: offline)")
    command.add_argument("--base-url", help="LLM endpoint, an http(s) URL such as http://127.0.0.1:8080/v1")
    command.add_argument("--model", help="LLM model name")
    command.add_argument(
        "--llm-deadline",
        type=number(0.001, MAX_DURATION_S),
        metavar="SECONDS",
        help="longest an LLM parse may wait, retries included, before the offline parser answers (default 30)",
    )
    command.add_argument(
        "--llm-timeout", type=number(0.001, MAX_DURATION_S), metavar="SECONDS", help="one LLM request (default 20)"
    )
    command.add_argument(
        "--llm-attempts",
        type=count(1, 100),
        metavar="N",
        help="LLM requests per parse, when they fail transiently (default 3)",
    )
    command.add_argument(
        "--llm-cross-check",
        choices=CROSS_CHECK_POLICIES,
        help="when the LLM's answer and the offline parse differ: 'offline' (default) answers with the offline parse, "
        "'cover' only if the LLM left out a reference, 'llm' never (docs/parsing.md)",
    )
    command.add_argument(
        "--no-llm-cache", action="store_true", help="ask the LLM again instead of reusing stored answers"
    )


def _config(args):
    from ocplace.models.parsing import config

    given = {
        "base_url": args.base_url,
        "model": args.model,
        "deadline_s": args.llm_deadline,
        "timeout_s": args.llm_timeout,
        "max_attempts": args.llm_attempts,
        "cross_check": args.llm_cross_check,
        "use_cache": False if args.no_llm_cache else None,
    }
    # LLMConfig checks the values (an ftp:// URL is an LLMConfigError, exit status 2).
    llm = config.LLMConfig(**{name: value for name, value in given.items() if value is not None})
    return dataclasses.replace(config.default_config(), parser=args.parser, llm=llm)


def _parse(args) -> int:
    from ocplace.models.parsing import make_parser

    tuples = make_parser(config=_config(args)).parse(args.instruction)
    if args.json:
        print(json.dumps([dataclasses.asdict(t) for t in tuples], indent=2))
        return 0
    for item in tuples:
        how = "direct" if item.provenance == "direct" else f"snapped, similarity {item.similarity:.2f}"
        print(f"{item.reference!r:40s} {item.relation:12s} <- {item.relation_phrase!r} ({how})")
        if item.fallback_reason:
            print(f"  (offline fallback: {item.fallback_reason})")
    if tuples[0].disagreement:
        print(f"  (the LLM and the offline parser differ: {tuples[0].disagreement}; answered by {tuples[0].parser})")
    return 0


def _parse_eval(args) -> int:
    import time
    from pathlib import Path

    from ocplace.models.parsing import evaluation, make_parser

    parser = make_parser(config=_config(args))
    names = evaluation.EVAL_OBJECT_NAMES
    if args.names:
        names = tuple(n.strip() for n in Path(args.names).read_text().splitlines() if n.strip())
    snapper_holder: Any = getattr(parser, "offline", parser)  # the offline parser, alone or inside the LLM's
    start = time.perf_counter()
    _ = snapper_holder.snapper  # load and compile the encoder outside the timed runs
    print(f"sentence encoder loaded and compiled in {time.perf_counter() - start:.1f} s")
    sets = {
        "seen": evaluation.generated_cases("seen", args.num, args.seed, names),
        "unseen": evaluation.generated_cases("unseen", args.num, args.seed + 1, names),
    }
    freeform_path = Path(args.freeform) if args.freeform else evaluation.FREEFORM_PATH
    for split in ("dev", "test", "blind"):
        sets[f"free-{split}"] = evaluation.freeform_cases(freeform_path, split)
    sets["free-all"] = evaluation.freeform_cases(freeform_path)
    snaps = evaluation.expression_snapping(snapper_holder.snapper)
    accepted = [s for s in snaps if s.accepted]
    print(
        f"encoder alone on the {len(snaps)} unseen relation expressions: nearest relation right "
        f"for {sum(s.nearest == s.relation for s in snaps)}; past the thresholds: "
        f"{len(accepted)} ({sum(s.nearest == s.relation for s in accepted)} right), "
        f"refused {len(snaps) - len(accepted)}"
    )
    print(f"parser {parser.name}, {len(names)} object names")
    for set_name, cases in sets.items():
        if parser.name == "llm":  # the LLM's own answers, the offline parse and every cross-check policy
            if set_name != "free-all":  # its splits again: each instruction is asked once
                print(evaluation.evaluate_llm(parser, cases, set_name).summary(), flush=True)
            continue
        report = evaluation.evaluate(parser, cases, set_name)
        print(report.summary())
        for instruction, expected, got in report.failures[: args.show_failures]:
            print(f"    {instruction!r}\n      expected {expected}\n      got      {got}")
    return 0
