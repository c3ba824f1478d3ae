from bgap.runner.numerics import command

main = command("bgap.datasets.simulate")
if __name__ == "__main__":
    main()
