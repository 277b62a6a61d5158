import belief_nlp as bn


def test_builtins_load():
    names = bn.list_scenarios()
    assert {"paper-multi", "quad", "cube3d", "tutorial"} <= set(names)
    for n in names:
        sc = bn.load_scenario(n)
        assert sc.chi2 > 0
