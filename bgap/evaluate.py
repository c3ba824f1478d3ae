from bgap.runner.numerics import command

main = command("bgap.experiments.evaluate")
if __name__ == "__main__":
    main()
