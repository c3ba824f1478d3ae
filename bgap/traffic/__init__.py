"""The traffic bgap simulates: driver classes (IDM + MOBIL parameters, aggressive and
conservative) and the scenario (road, density, mix, reward) both simulators build."""
