"""softrom_gym._console: the one-line usage errors the command lines share."""

from softrom_gym._console import OneLineArgumentParser, unknown_option_hint


def test_the_unknown_option_hint_names_the_option_meant_for_each_unknown_option_only():
    parser = OneLineArgumentParser(prog="tool")
    parser.add_argument("--iterations")
    parser.add_argument("--seconds")
    # each unknown option, with its value cut: a prefix too short to be a close spelling
    # (argparse took it while abbreviations were allowed) and a typo
    assert unknown_option_hint(parser, ["--it", "3", "--secnds=2"]) == (
        " (did you mean --iterations for --it, --seconds for --secnds? tool --help lists the "
        "options)"
    )
    # a plain word is no option, even one spelled as an option's name is
    assert unknown_option_hint(parser, ["seconds"]) == " (tool --help lists the options)"
